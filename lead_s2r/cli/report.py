"""Verbs people read: ``table`` (a paper table of runs), ``report`` (a static web report), ``view`` (a log in Rerun)."""

import argparse
from pathlib import Path
from typing import Any


def cmd_table(args: argparse.Namespace) -> int:
    from lead_s2r.report.tables import build_table

    print(build_table(args.spec, args.runs, args.out), end="")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from lead_s2r.errors import UserError
    from lead_s2r.report.site import DEFAULT_WORST, build_report, build_site

    if (args.run_dir is None) == (args.runs is None):
        raise UserError("report: give one run folder (RUN) or many with --runs 'runs/*/*/seed*', not both or neither")
    if args.runs is None:
        if args.compare is not None:
            raise UserError("report: --compare A B compares models of --runs; give one run a --baseline instead")
        worst = DEFAULT_WORST if args.worst is None else args.worst
        index = build_report(args.run_dir, args.out, args.baseline, args.data, worst, args.samples, args.threshold)
    else:
        many_only = {"--baseline": args.baseline, "--data": args.data, "--samples": args.samples}
        wrong = [flag for flag, value in many_only.items() if value is not None]
        if wrong:
            raise UserError(f"report --runs: {wrong[0]} is for one run; --compare A B compares two models")
        worst = 1 if args.worst is None else args.worst
        index = build_site(args.runs, args.out, args.compare, worst, threshold=args.threshold)
    print(index)
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from lead_s2r.report.recording import write_recording

    print(write_recording(args.target, args.rrd, args.log, args.spawn))
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("table", help="a paper table from runs: mean ± std over seeds beside the paper's numbers")
    sub.add_argument(
        "--spec", required=True, help="table spec: a file, or a shipped name (table1 ... table5 in recipes/paper)"
    )
    sub.add_argument("--runs", required=True, nargs="+", help="run directories or glob patterns (runs/*/seed*)")
    sub.add_argument("--out", default=None, help="also write markdown, LaTeX, CSV (and the figure) here")
    sub.set_defaults(run=cmd_table)

    sub = verbs.add_parser("report", help="a static web report of scored runs: scores, worst samples, comparisons")
    sub.add_argument("run_dir", metavar="RUN", nargs="?", help="one run folder: scores.json files below it")
    sub.add_argument(
        "--runs",
        nargs="+",
        default=None,
        metavar="PATTERN",
        help="many runs: folders or glob patterns (runs/*/*/seed*); an index of all of them",
    )
    sub.add_argument(
        "--compare",
        nargs=2,
        default=None,
        metavar=("A", "B"),
        help="with --runs: model B against model A per scene (run ids ending with A, B: ego_mlp ltfv6)",
    )
    sub.add_argument("--out", required=True, help="folder to write the site to (index.html); replaced when complete")
    sub.add_argument("--baseline", default=None, metavar="RUN_B", help="a second run on the same data to compare")
    sub.add_argument("--data", nargs="+", type=Path, default=None, help="converted folders (default: scores.json's)")
    sub.add_argument("--worst", type=int, default=None, help="samples shown per metric, worst first (5; --runs: 1)")
    sub.add_argument("--samples", nargs="+", default=None, metavar="KEY", help="show these sample keys instead")
    sub.add_argument("--threshold", type=float, default=1e-9, help="smallest per-sample difference a comparison lists")
    sub.set_defaults(run=cmd_report)

    sub = verbs.add_parser("view", help="a converted log (or a run's predictions on it) as a Rerun recording (.rrd)")
    sub.add_argument("target", metavar="LOG_OR_RUN", help="a converted folder, or a scored run (its data and plans)")
    sub.add_argument("--rrd", required=True, help="the recording file to write (FILE.rrd)")
    sub.add_argument("--log", default=None, help="the log id to record (needed when the folder holds several)")
    sub.add_argument("--spawn", action="store_true", help="also open the recording in the Rerun viewer")
    sub.set_defaults(run=cmd_view)
