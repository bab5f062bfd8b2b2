"""Verbs that make and read converted data: ``adapters``, ``synth``, ``convert``, ``inspect``, ``twin-data``."""

import argparse
import importlib
import json
import sys
import types
import typing
from collections import Counter
from pathlib import Path
from typing import Any

from lead_s2r.cli.common import add_executor_arguments
from lead_s2r.errors import UserError
from lead_s2r.registry import ADAPTER_GROUP, RegistryError, load, missing_requirements, names


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
            raise UserError(f"unknown option {token!r} for adapter {adapter_cls.name}; it takes: {known}")
        value = next(tokens, None)
        if value is None:
            raise UserError(f"option {token} of adapter {adapter_cls.name} needs a value")
        try:
            options[name] = _cast(value, hints[name])
        except ValueError as err:
            raise UserError(f"option {token} of adapter {adapter_cls.name}: {err}") from None
    return options


def cmd_adapters(args: argparse.Namespace) -> int:
    for name in names(ADAPTER_GROUP):
        try:
            cls = load(name)
        except RegistryError as err:
            print(f"{name:12s} {'?':8s} unavailable: {err}")
            continue
        print(f"{name:12s} {cls.version:8s} extra: {_extra_state(cls.extras)}")
    return 0


def _extra_state(extra: str | None) -> str:
    if not extra:
        return "- (none needed)"
    missing = missing_requirements(extra)
    if not missing:
        return f"{extra} (installed)"
    return f"{extra} (missing {', '.join(missing)}: pip install 'lead-s2r[{extra}]')"


def cmd_synth(args: argparse.Namespace) -> int:
    try:
        module = importlib.import_module(f"lead_s2r.synthetic.{args.name}")
    except ModuleNotFoundError:
        raise UserError(f"no synthetic generator {args.name!r}; choose carla_lead, navsim, wod_e2e or py123d") from None
    module.generate(Path(args.out), count=args.count, seed=args.seed)
    print(f"wrote synthetic {args.name} data to {args.out}: {_written(args.name, Path(args.out))}")
    return 0


def _written(name: str, out: Path) -> str:
    """What a generator wrote, as its adapter will see it (logs per split), and the files and bytes on disk."""
    files = [path for path in out.rglob("*") if path.is_file()]
    size = f"{len(files)} files, {sum(path.stat().st_size for path in files) / 1e6:.1f} MB"
    if name not in names(ADAPTER_GROUP):
        return size
    splits = Counter(log.split for log in load(name)().list_logs(out))
    logs = ", ".join(f"{count} {split}" for split, count in sorted(splits.items()))
    return f"logs {logs} ({size}); next: lead-s2r convert {name} --src {out} --out DATA (docs/datasets/{name}.md)"


def cmd_convert(args: argparse.Namespace, extra: list[str]) -> int:
    from lead_s2r.convert import conversion_executor, convert
    from lead_s2r.shards import ERRORS

    cls = load(args.adapter)
    options = adapter_options(cls, extra)
    try:
        adapter = cls(**options)
    except (ValueError, TypeError) as err:  # an adapter's constructor validates its options
        raise UserError(f"adapter {args.adapter}: {err}; see docs/datasets/{args.adapter}.md for its options") from None
    result = convert(
        adapter,
        args.src,
        args.out,
        executor=conversion_executor(args.workers, args.executor, args.address),
        shard_size=args.shard_size,
        limit_logs=args.limit_logs,
        force=args.force,
        progress=not args.quiet,
    )
    done = f"{result.logs_resumed} already done, {len(result.skipped)} skipped, {len(result.errors)} failed"
    bad = f", {len(result.bad_records)} bad records left out" if result.bad_records else ""
    print(f"{result.samples} samples from {result.logs_converted} logs ({done}{bad}) -> {args.out}")
    for error in result.errors:
        print(f"  failed {error['log']}: {error['error']}", file=sys.stderr)
    for record in result.bad_records:
        print(f"  bad record: {record['error']}", file=sys.stderr)
    if not result.ok:
        print(f"  details: {Path(args.out) / ERRORS}", file=sys.stderr)
    return 0 if result.ok else 1


def cmd_inspect(args: argparse.Namespace) -> int:
    from lead_s2r.report.inspection import inspect_dataset, list_keys

    if args.list:
        print("\n".join(list_keys(args.path)))
        return 0
    quick = args.n if args.quick else None
    report = inspect_dataset(args.path, quick=quick, png=args.png, key=args.key, progress=not args.no_progress)
    print(json.dumps(report, indent=2))
    return 1 if report["invalid"] else 0


def cmd_twin_data(args: argparse.Namespace) -> int:
    from lead_s2r.demo.twin_data import write_twin_data

    names = write_twin_data(Path(args.out), workers=args.workers)
    print(f"wrote {', '.join(names)} under {Path(args.out) / 'data'}; run smoke twins in {args.out} (docs/recipes.md)")
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("adapters", help="list registered adapters with their version and pip extra")
    sub.set_defaults(run=cmd_adapters)

    sub = verbs.add_parser("synth", help="write synthetic raw data in a source's true on-disk format")
    sub.add_argument("name", help="carla_lead | navsim | navsim_navhard | wod_e2e | py123d")
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
    add_executor_arguments(sub, "processes converting on this machine (the output is the same)")
    sub.add_argument("--shard-size", type=int, default=1000, help="samples per shard (closed at a log boundary)")
    sub.add_argument("--limit-logs", type=int, default=None)
    sub.add_argument("--force", action="store_true", help="start over instead of resuming")
    sub.add_argument("--quiet", action="store_true", help="no progress bar")
    sub.set_defaults(run=cmd_convert)

    sub = verbs.add_parser("inspect", help="counts, schema check, statistics and a picture of a converted folder")
    sub.add_argument("path")
    sub.add_argument("--quick", action="store_true", help="validate the first --n samples only (default: every one)")
    sub.add_argument("--n", type=int, default=32, help="samples to validate with --quick")
    sub.add_argument("--no-progress", action="store_true", help="no progress bar")
    sub.add_argument("--png", default=None, help="draw one sample (cameras + BEV) to this file")
    sub.add_argument("--key", default=None, help="sample to draw (default: of those checked, the one turning most)")
    sub.add_argument("--list", action="store_true", help="list every sample's key, split, log, frame and speed")
    sub.set_defaults(run=cmd_inspect)

    sub = verbs.add_parser("twin-data", help="small synthetic data under every data/ path the paper recipes read")
    sub.add_argument("--out", default=".", help="the folder to run smoke twins in (data/ and raw/ go here)")
    sub.add_argument("--workers", type=int, default=1)
    sub.set_defaults(run=cmd_twin_data)
