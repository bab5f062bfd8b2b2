"""The ``lead-s2r`` command line.

Every mistake a user can fix is a :class:`~lead_s2r.errors.UserError`, raised wherever it is found; ``main()``
prints it as one line with exit status 2 (``--debug`` anywhere on the line shows the traceback). argparse's own
mistakes are routed through the same path, so every verb fails alike. Inputs are checked before any output folder
is created.
"""

import argparse
import contextlib
import importlib
import json
import os
import shutil
import sys
import types
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NoReturn

from lead_s2r import __version__
from lead_s2r.errors import UserError
from lead_s2r.registry import ADAPTER_GROUP, SCORER_GROUP, RegistryError, load, missing_requirements, names
from lead_s2r.submit.arguments import add_submit_parser

LIGHTNING_VERBS = ("fit", "validate", "test", "predict")
DEBUG_FLAG = "--debug"
USER_ERROR_STATUS = 2
#: A closed stdout: the status a shell gives a process ended by SIGPIPE (128 + 13).
BROKEN_PIPE_STATUS = 141


class _Parser(argparse.ArgumentParser):
    """argparse whose mistakes are :class:`UserError`, so they print as one line like every other."""

    def error(self, message: str) -> NoReturn:
        raise UserError(f"{self.prog}: {message} (see {self.prog} --help)")


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
    """``wod (installed)``, or what is missing and the command that installs it."""
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
    splits: dict[str, int] = {}
    for log in load(name)().list_logs(out):
        splits[log.split] = splits.get(log.split, 0) + 1
    logs = ", ".join(f"{count} {split}" for split, count in sorted(splits.items()))
    return f"logs {logs} ({size}); next: lead-s2r convert {name} --src {out} --out DATA (docs/datasets/{name}.md)"


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor`` and ``--address``: where the jobs of ``convert`` and ``score`` run."""
    parser.add_argument(
        "--executor",
        choices=["processes", "ray"],
        default="processes",
        help="processes: --workers on this machine; ray: a task per job on a Ray cluster (pip install lead-s2r[ray])",
    )
    parser.add_argument(
        "--address", default=None, help="with --executor ray: auto, or HOST:PORT of the head (default: RAY_ADDRESS)"
    )


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


def cmd_score(args: argparse.Namespace) -> int:
    from lead_s2r.processes import make_executor
    from lead_s2r.scoring.run import planner_predictions, score_predictions

    options: dict[str, Any] = {"allow_missing": not args.strict}
    for option in args.option:
        name, equals, value = option.partition("=")
        if not name or not equals:
            raise UserError(f"--option {option!r}: expected KEY=VALUE, e.g. --option floor=4")
        try:
            options[name] = json.loads(value)  # numbers, booleans, lists
        except json.JSONDecodeError:
            options[name] = value
    if args.reference_cache:
        options["reference_cache"] = args.reference_cache
    scorer_module = load(args.metric, SCORER_GROUP).__module__  # the workers' forkserver imports it once
    executor = make_executor(args.workers, args.executor, args.address, preload=[scorer_module])
    data, out = [Path(folder) for folder in args.data], Path(args.out)
    with removed_on_failure(out):
        predictions = Path(args.predictions) if args.predictions else None
        if predictions is None:
            path = out / f"predictions-{args.planner}.parquet"
            predictions = planner_predictions(args.planner, data, path, args.split)
        selection = {"split": args.split, "tag": args.tag}
        summary = score_predictions(args.metric, predictions, data, out, executor=executor, **selection, **options)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        from rich.console import Console

        from lead_s2r.report.score_summary import score_table

        Console().print(score_table(summary))
        print(f"wrote {out / 'scores.json'} and scores.parquet ({summary['seconds']:.1f} s)")
    return 0


@contextlib.contextmanager
def removed_on_failure(out: Path) -> Iterator[None]:
    """What the block writes under ``out`` is removed if it fails (``out`` too, if the block made it): a planner's
    predictions or a scores.parquet without its scores.json must not pass for a result."""
    before = set(out.rglob("*")) if out.exists() else None
    try:
        yield
    except BaseException:
        if before is None:
            shutil.rmtree(out, ignore_errors=True)
        else:
            for path in sorted(set(out.rglob("*")) - before, reverse=True):  # a folder's files before the folder
                path.rmdir() if path.is_dir() else path.unlink()
        raise


def cmd_submit(args: argparse.Namespace) -> int:
    """Write a leaderboard submission (``navsim``, ``wod-e2e``) or, with ``--check``, re-read one."""
    if args.check:
        report = _check_submission(Path(args.check))
    elif args.target == "navsim":
        from lead_s2r.submit.navsim import NavsimMetadata, write_navsim

        metadata = NavsimMetadata(args.team, args.authors, args.email, args.institution, args.country)
        predictions = [Path(p) for p in args.predictions]
        report = write_navsim(Path(args.out), metadata, predictions, [Path(d) for d in args.data], args.two_stage)
    elif args.target == "wod-e2e":
        from lead_s2r.submit.wod_e2e import WodMetadata, write_wod

        metadata = WodMetadata(
            account_name=args.account,
            unique_method_name=args.method,
            authors=args.authors,
            num_model_parameters=args.num_params,
            uses_public_model_pretraining=args.pretrained,
            affiliation=args.affiliation,
            description=args.description,
            method_link=args.method_link,
            public_model_names=args.public_models,
        )
        data = [Path(d) for d in args.data]
        report = write_wod(Path(args.out), metadata, Path(args.predictions), data, args.split, args.shards)
    else:
        raise UserError("lead-s2r submit needs navsim, wod-e2e or --check FILE (see lead-s2r submit --help)")
    print(json.dumps(report, indent=2))
    return 0


def _check_submission(path: Path) -> dict[str, Any]:
    """A ``.pkl`` is a NAVSIM submission; a tar.gz, a folder or a ``.binproto-*`` shard is WOD-E2E's."""
    from lead_s2r.submit.common import SubmissionError

    if not path.exists():
        raise SubmissionError(f"{path}: no such submission file (--check)")
    if path.suffix == ".pkl":
        from lead_s2r.submit.navsim import check_navsim

        return check_navsim(path)
    from lead_s2r.submit.wod_e2e import check_wod

    return check_wod(path)


def cmd_carla_metrics(args: argparse.Namespace) -> int:
    from lead_s2r.scoring.carla_leaderboard import carla_metrics

    summary = carla_metrics(args.results, args.benchmark, Path(args.out), args.routes)
    print(json.dumps(summary["aggregates"], indent=2))
    return 0


def cmd_closed_loop_check(args: argparse.Namespace) -> int:
    from lead_s2r.closed_loop.check import check_run
    from lead_s2r.closed_loop.checkpoint import UnsupportedCheckpoint

    try:
        result = check_run(args.path, ticks=args.ticks)
    except (UnsupportedCheckpoint, FileNotFoundError) as err:
        raise UserError(f"closed-loop check: {err}") from None
    print("\n".join(result.lines()))
    return 0


def cmd_table(args: argparse.Namespace) -> int:
    from lead_s2r.report.tables import build_table

    print(build_table(args.spec, args.runs, args.out), end="")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from lead_s2r.report.site import build_report

    index = build_report(args.run_dir, args.out, args.baseline, args.data, args.worst, args.samples, args.threshold)
    print(index)
    return 0


def cmd_export_lead(args: argparse.Namespace) -> int:
    from lead_s2r.training.lead_export import export_run

    print(f"wrote {export_run(Path(args.run_dir), Path(args.out))} (config.json + model_0000.pth, LEAD's format)")
    return 0


def cmd_quickstart(args: argparse.Namespace) -> int:
    from lead_s2r.demo.quickstart import quickstart

    quickstart(Path(args.out), workers=args.workers)
    return 0


def cmd_twin_data(args: argparse.Namespace) -> int:
    from lead_s2r.demo.twin_data import write_twin_data

    names = write_twin_data(Path(args.out), workers=args.workers)
    print(f"wrote {', '.join(names)} under {Path(args.out) / 'data'}; run smoke twins in {args.out} (docs/recipes.md)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lead-s2r",
        description="Convert driving datasets to one schema, train, score and make the paper's tables.",
        epilog="Training: lead-s2r fit|validate|test|predict --config recipes/... (LightningCLI; see --help there).",
    )
    parser.add_argument("--version", action="version", version=f"lead-s2r {__version__}")
    parser.add_argument(DEBUG_FLAG, action="store_true", help="show the traceback of a user error (any position)")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

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
    sub.add_argument(
        "--workers", type=int, default=1, help="processes converting on this machine (the output is the same)"
    )
    add_executor_arguments(sub)
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

    sub = verbs.add_parser("score", help="score predictions open-loop")
    sub.add_argument("--metric", required=True, help=f"one of the {SCORER_GROUP} entry points")
    source = sub.add_mutually_exclusive_group(required=True)
    source.add_argument("--predictions", help="predictions.parquet of a model")
    source.add_argument("--planner", choices=("human", "constant-velocity"), help="score a model-free planner instead")
    sub.add_argument("--data", required=True, nargs="+", help="converted folder(s)")
    sub.add_argument("--out", required=True)
    sub.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="scorer configuration")
    sub.add_argument("--split", default=None, help="score only this split of --data (e.g. val)")
    sub.add_argument(
        "--tag", default=None, help="score only the samples with this tag (e.g. scene_filter:pedestrians_ahead)"
    )
    sub.add_argument("--strict", action="store_true", help="a sample without a prediction is an error")
    sub.add_argument("--json", action="store_true", help="print scores.json instead of the summary table")
    sub.add_argument("--reference-cache", default=None, help="PDMS: folder caching PDM-Closed references per sample")
    sub.add_argument(
        "--workers", type=int, default=1, help="processes scoring on this machine (the scores are the same)"
    )
    add_executor_arguments(sub)
    sub.set_defaults(run=cmd_score)

    add_submit_parser(verbs, cmd_submit)

    sub = verbs.add_parser("carla-metrics", help="CARLA leaderboard 2.0 results -> DS, RC, IS, SR, NDS, per 100 km")
    sub.add_argument("results", nargs="+", help="results JSON files (one per seed or route batch)")
    sub.add_argument("--benchmark", required=True, choices=["bench2drive", "longest6", "town13"])
    sub.add_argument("--out", required=True)
    sub.add_argument("--routes", default=None, help="the benchmark's routes XML, to name the missing routes")
    sub.set_defaults(run=cmd_carla_metrics)

    sub = verbs.add_parser("closed-loop", help="offline checks of a run before a CARLA evaluation")
    checks = sub.add_subparsers(dest="check", required=True, metavar="CHECK")
    sub = checks.add_parser(
        "check", help="the agent's setup, sensors and a few ticks on synthetic sensor data, no CARLA server"
    )
    sub.add_argument("path", metavar="RUN", help="run folder (runs/carla/<name>/seed<k>), checkpoint, or agent YAML")
    sub.add_argument("--ticks", type=int, default=5, help="ticks to drive (the first brakes, as in a real route)")
    sub.set_defaults(run=cmd_closed_loop_check)

    sub = verbs.add_parser("table", help="a paper table from runs: mean ± std over seeds beside the paper's numbers")
    sub.add_argument(
        "--spec", required=True, help="table spec: a file, or a shipped name (table1 ... table5 in recipes/paper)"
    )
    sub.add_argument("--runs", required=True, nargs="+", help="run directories or glob patterns (runs/*/seed*)")
    sub.add_argument("--out", default=None, help="also write markdown, LaTeX, CSV (and the figure) here")
    sub.set_defaults(run=cmd_table)

    sub = verbs.add_parser("report", help="a static web report of a scored run: summary, worst samples, comparison")
    sub.add_argument("run_dir", metavar="RUN", help="run folder: scores.json files below it (lead-s2r score --out)")
    sub.add_argument("--out", required=True, help="folder to write the site to (index.html); replaced when complete")
    sub.add_argument("--baseline", default=None, metavar="RUN_B", help="a second run on the same data to compare")
    sub.add_argument("--data", nargs="+", type=Path, default=None, help="converted folders (default: scores.json's)")
    sub.add_argument("--worst", type=int, default=5, help="samples shown per metric, worst first")
    sub.add_argument("--samples", nargs="+", default=None, metavar="KEY", help="show these sample keys instead")
    sub.add_argument("--threshold", type=float, default=1e-9, help="smallest per-sample difference a comparison lists")
    sub.set_defaults(run=cmd_report)

    sub = verbs.add_parser("export-lead", help="a run trained with LEAD's architecture -> a LEAD checkpoint folder")
    sub.add_argument("run_dir", metavar="RUN", help="run folder (its checkpoints/last.ckpt) or a .ckpt file")
    sub.add_argument("--out", required=True, help="folder for config.json + model_0000.pth")
    sub.set_defaults(run=cmd_export_lead)

    sub = verbs.add_parser("quickstart", help="synthetic data -> smoke runs -> held-out scores -> Table 4")
    sub.add_argument("--out", default="quickstart")
    sub.add_argument("--workers", type=int, default=2)
    sub.set_defaults(run=cmd_quickstart)

    sub = verbs.add_parser("twin-data", help="small synthetic data under every data/ path the paper recipes read")
    sub.add_argument("--out", default=".", help="the folder to run smoke twins in (data/ and raw/ go here)")
    sub.add_argument("--workers", type=int, default=1)
    sub.set_defaults(run=cmd_twin_data)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one verb; a :class:`UserError` is one line on stderr and exit status 2 (its traceback with --debug)."""
    from_shell = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = DEBUG_FLAG in argv
    argv = [arg for arg in argv if arg != DEBUG_FLAG]
    if from_shell:  # LightningCLI reads sys.argv itself (and warns when given both)
        sys.argv[1:] = argv
    try:
        status = _run(argv, from_shell)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at the interpreter's exit
        return status
    except UserError as err:
        if debug:
            raise
        print(f"error: {err.one_line()}", file=sys.stderr)
        return USER_ERROR_STATUS
    except BrokenPipeError:  # `lead-s2r ... | head`: the reader has all it wanted
        _quiet_stdout()
        return BROKEN_PIPE_STATUS


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush of the closed pipe raises nothing either."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _run(argv: list[str], from_shell: bool) -> int:
    if argv and argv[0] in LIGHTNING_VERBS:
        from lead_s2r.training.cli import run_lightning_cli

        run_lightning_cli(None if from_shell else argv)
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
