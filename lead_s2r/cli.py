"""The ``lead-s2r`` command line."""

import argparse
import importlib
import json
import sys
import types
import typing
from pathlib import Path
from typing import Any

from lead_s2r import __version__
from lead_s2r.registry import ADAPTER_GROUP, SCORER_GROUP, RegistryError, load, names

LIGHTNING_VERBS = ("fit", "validate", "test", "predict")


def _cast(value: str, annotation: Any) -> Any:
    """Turn a command-line string into the type an adapter's ``__init__`` declares."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):  # X | None -> X
        annotation = next(a for a in typing.get_args(annotation) if a is not type(None))
    if annotation is bool:
        if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"expected a boolean, got {value!r}")
        return value.lower() in ("true", "1", "yes")
    if annotation in (int, float, Path):
        return annotation(value)
    return value


def adapter_options(adapter_cls: type, argv: list[str]) -> dict[str, Any]:
    """Parse ``--name value`` pairs into keyword arguments of ``adapter_cls.__init__``, typed by its hints."""
    hints = typing.get_type_hints(adapter_cls.__init__)
    options: dict[str, Any] = {}
    tokens = iter(argv)
    for token in tokens:
        name = token[2:].replace("-", "_") if token.startswith("--") else None
        if name is None or name not in hints or name == "return":
            known = ", ".join(f"--{n.replace('_', '-')}" for n in hints if n != "return") or "none"
            raise SystemExit(f"error: unknown option {token!r} for adapter {adapter_cls.name}; it takes: {known}")
        value = next(tokens, None)
        if value is None:
            raise SystemExit(f"error: option {token} needs a value")
        try:
            options[name] = _cast(value, hints[name])
        except ValueError as err:
            raise SystemExit(f"error: option {token}: {err}") from None
    return options


def cmd_adapters(args: argparse.Namespace) -> int:
    for name in names(ADAPTER_GROUP):
        try:
            cls = load(name)
            print(f"{name:12s} {cls.version:8s} extra: {cls.extras or '-'}")
        except RegistryError as err:
            print(f"{name:12s} {'?':8s} unavailable: {err}")
    return 0


def cmd_synth(args: argparse.Namespace) -> int:
    try:
        module = importlib.import_module(f"lead_s2r.synthetic.{args.name}")
    except ModuleNotFoundError:
        raise SystemExit(f"error: no synthetic generator {args.name!r}") from None
    module.generate(Path(args.out), count=args.count, seed=args.seed)
    print(f"wrote synthetic {args.name} data to {args.out}")
    return 0


def cmd_convert(args: argparse.Namespace, extra: list[str]) -> int:
    from lead_s2r.convert import convert

    try:
        cls = load(args.adapter)
    except RegistryError as err:
        raise SystemExit(f"error: {err}") from None
    adapter = cls(**adapter_options(cls, extra))
    result = convert(
        adapter,
        args.src,
        args.out,
        workers=args.workers,
        shard_size=args.shard_size,
        limit_logs=args.limit_logs,
        force=args.force,
        progress=not args.quiet,
    )
    done = f"{result.logs_resumed} already done, {len(result.skipped)} skipped, {len(result.errors)} failed"
    print(f"{result.samples} samples from {result.logs_converted} logs ({done}) -> {args.out}")
    for error in result.errors:
        print(f"  failed {error['log']}: {error['error']}", file=sys.stderr)
    return 0 if result.ok else 1


def cmd_inspect(args: argparse.Namespace) -> int:
    from lead_s2r.inspection import inspect_dataset

    try:
        report = inspect_dataset(args.path, n=args.n, png=args.png, key=args.key)
    except KeyError as err:
        raise SystemExit(f"error: {err.args[0]}") from None
    print(json.dumps(report, indent=2))
    return 1 if report["invalid"] else 0


def cmd_score(args: argparse.Namespace) -> int:
    from lead_s2r.scoring.run import planner_predictions, score_predictions

    options = {}
    for option in args.option:
        name, _, value = option.partition("=")
        try:
            options[name] = json.loads(value)  # numbers, booleans, lists
        except json.JSONDecodeError:
            options[name] = value
    if args.reference_cache:
        options["reference_cache"] = args.reference_cache
    data = [Path(folder) for folder in args.data]
    predictions = Path(args.predictions) if args.predictions else None
    if predictions is None:
        predictions = planner_predictions(args.planner, data, Path(args.out) / f"predictions-{args.planner}.parquet")
    summary = score_predictions(args.metric, predictions, data, Path(args.out), **options)
    print(json.dumps(summary, indent=2))
    return 0


def cmd_quickstart(args: argparse.Namespace) -> int:
    from lead_s2r.quickstart import quickstart

    quickstart(Path(args.out), workers=args.workers)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lead-s2r",
        description=__doc__,
        epilog="Training: lead-s2r fit|validate|test|predict --config recipes/... (LightningCLI; see --help there).",
    )
    parser.add_argument("--version", action="version", version=f"lead-s2r {__version__}")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    sub = verbs.add_parser("adapters", help="list registered adapters with their version and pip extra")
    sub.set_defaults(run=cmd_adapters)

    sub = verbs.add_parser("synth", help="write synthetic raw data in a source's true on-disk format")
    sub.add_argument("name", help="carla_lead | navsim | navsim_navhard | wod_e2e")
    sub.add_argument("--out", required=True)
    sub.add_argument("--count", "--routes", "--logs", "--segments", type=int, default=None, help="number of logs")
    sub.add_argument("--seed", type=int, default=0)
    sub.set_defaults(run=cmd_synth)

    sub = verbs.add_parser(
        "convert",
        help="convert raw data to schema v1 shards",
        epilog="Further --options are passed to the adapter (e.g. --rig both for carla_lead).",
    )
    sub.add_argument("adapter")
    sub.add_argument("--src", required=True)
    sub.add_argument("--out", required=True)
    sub.add_argument("--workers", type=int, default=1)
    sub.add_argument("--shard-size", type=int, default=1000, help="samples per shard (closed at a log boundary)")
    sub.add_argument("--limit-logs", type=int, default=None)
    sub.add_argument("--force", action="store_true", help="start over instead of resuming")
    sub.add_argument("--quiet", action="store_true", help="no progress bar")
    sub.set_defaults(run=cmd_convert)

    sub = verbs.add_parser("inspect", help="counts, schema check, statistics and a picture of a converted folder")
    sub.add_argument("path")
    sub.add_argument("--n", type=int, default=32, help="samples to validate")
    sub.add_argument("--png", default=None, help="draw one sample (cameras + BEV) to this file")
    sub.add_argument("--key", default=None, help="sample to draw (default: the first)")
    sub.set_defaults(run=cmd_inspect)

    sub = verbs.add_parser("score", help="score predictions open-loop")
    sub.add_argument("--metric", required=True, help=f"one of the {SCORER_GROUP} entry points")
    source = sub.add_mutually_exclusive_group(required=True)
    source.add_argument("--predictions", help="predictions.parquet of a model")
    source.add_argument("--planner", choices=("human", "constant-velocity"), help="score a model-free planner instead")
    sub.add_argument("--data", required=True, nargs="+", help="converted folder(s)")
    sub.add_argument("--out", required=True)
    sub.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="scorer configuration")
    sub.add_argument("--reference-cache", default=None, help="PDMS: folder caching PDM-Closed references per sample")
    sub.set_defaults(run=cmd_score)

    sub = verbs.add_parser("quickstart", help="synthetic data -> conversion -> baseline predictions -> scores")
    sub.add_argument("--out", default="quickstart")
    sub.add_argument("--workers", type=int, default=2)
    sub.set_defaults(run=cmd_quickstart)
    return parser


def main(argv: list[str] | None = None) -> int:
    from_shell = argv is None
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in LIGHTNING_VERBS:
        from lead_s2r.training.cli import run_lightning_cli

        run_lightning_cli(None if from_shell else argv)  # None: LightningCLI reads sys.argv itself
        return 0
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if args.verb == "convert":
        return cmd_convert(args, extra)
    if extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
