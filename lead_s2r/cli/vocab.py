"""Verbs for trajectory vocabularies: ``vocab score`` (every sub-score of every entry in every scene, GTRS's targets)
and ``vocab build`` (k-means over the logged futures)."""

import argparse
import time
from pathlib import Path
from typing import Any

from lead_s2r.cli.common import add_executor_arguments


def cmd_vocab_score(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from lead_s2r.processes import make_executor
    from lead_s2r.scoring import vocab_targets

    executor = make_executor(args.workers, args.executor, args.address, preload=[vocab_targets.__name__])
    start, done = time.perf_counter(), {"scenes": 0, "entries": 0}
    columns = (
        TextColumn("[bold]vocab score"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
    )  # fmt: skip
    with Progress(*columns, disable=args.quiet) as progress:
        task = progress.add_task("scenes", total=None, rate="")

        def on_job(scenes: int, entries: int, total: int) -> None:
            done["scenes"] += scenes
            done["entries"] += entries
            seconds = max(time.perf_counter() - start, 1e-9)
            rate = f"{done['scenes'] / seconds:.2f} scenes/s, {done['entries'] / seconds:,.0f} entries/s"
            progress.update(task, completed=done["scenes"], total=total, rate=rate)

        manifest = vocab_targets.score_data(
            Path(args.vocab), [Path(folder) for folder in args.data], Path(args.out), args.metric, args.interval,
            args.progress, not args.no_human_filter, args.split, executor, on_job,
        )  # fmt: skip
    failed = f", {len(manifest['failed'])} failed (see {vocab_targets.MANIFEST})" if manifest["failed"] else ""
    print(f"scored {manifest['entries']} entries in {manifest['scenes']} scenes{failed} -> {args.out}")
    return 0


def cmd_vocab_build(args: argparse.Namespace) -> int:
    from lead_s2r.scoring.vocab_targets import build_vocabulary

    vocabulary = build_vocabulary([Path(folder) for folder in args.data], args.size, Path(args.out), args.seed,
                                  args.split)  # fmt: skip
    print(f"wrote a {vocabulary.shape} vocabulary to {args.out}")
    return 0


def add_verbs(verbs: Any) -> None:
    group = verbs.add_parser("vocab", help="trajectory vocabularies: score every entry per scene, build one")
    vocab_verbs = group.add_subparsers(dest="vocab_verb", required=True, metavar="VERB")
    sub = vocab_verbs.add_parser("score", help="every PDMS / EPDMS sub-score of every entry in every scene")
    sub.add_argument("--vocab", required=True, help="(V, K, 3) .npy of ego-frame poses (GTRS: (V, 40, 3) at 0.1 s)")
    sub.add_argument("--data", required=True, nargs="+", help="converted NAVSIM folder(s), converted with maps")
    sub.add_argument("--metric", default="pdms@navsim-1.1", choices=("pdms@navsim-1.1", "epdms@navsim-2.2"))
    sub.add_argument("--out", required=True, help="folder for vocab_scores.pkl / .parquet and vocab_manifest.json")
    sub.add_argument("--interval", type=float, default=0.1, help="seconds between an entry's poses (GTRS: 0.1)")
    sub.add_argument(
        "--progress", default="pair", choices=("pair", "vocabulary"),
        help="EP normalised over [PDM-Closed, entry] (NAVSIM's) or over the whole vocabulary (GTRS's targets)",
    )  # fmt: skip
    sub.add_argument(
        "--no-human-filter", action="store_true",
        help="EPDMS without v2.2's human penalty filter (SimScale's GTRS targets: with --progress vocabulary)",
    )  # fmt: skip
    sub.add_argument("--split", default=None, help="score only this split of --data")
    sub.add_argument("--quiet", action="store_true", help="no progress bar")
    add_executor_arguments(sub, "processes scoring on this machine (the files are the same)")
    sub.set_defaults(run=cmd_vocab_score)

    sub = vocab_verbs.add_parser("build", help="k-means over the logged futures: a (size, 40, 3) vocabulary")
    sub.add_argument("--data", required=True, nargs="+", help="converted folder(s)")
    sub.add_argument("--size", type=int, default=8192, help="entries")
    sub.add_argument("--out", required=True, help="the .npy to write")
    sub.add_argument("--seed", type=int, default=0)
    sub.add_argument("--split", default=None, help="cluster only this split of --data")
    sub.set_defaults(run=cmd_vocab_build)
