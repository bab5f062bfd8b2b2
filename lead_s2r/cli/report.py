"""Verbs people read: ``table`` (a paper table from runs) and ``report`` (the static web report)."""

import argparse
from pathlib import Path
from typing import Any


def cmd_table(args: argparse.Namespace) -> int:
    from lead_s2r.report.tables import build_table

    print(build_table(args.spec, args.runs, args.out), end="")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from lead_s2r.report.site import build_report

    index = build_report(args.run_dir, args.out, args.baseline, args.data, args.worst, args.samples, args.threshold)
    print(index)
    return 0


def add_verbs(verbs: Any) -> None:
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
