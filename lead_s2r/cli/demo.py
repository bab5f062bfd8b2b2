"""``lead-s2r quickstart``: synthetic data -> smoke runs -> held-out scores -> Table 4 -> report."""

import argparse
from pathlib import Path
from typing import Any


def cmd_quickstart(args: argparse.Namespace) -> int:
    from lead_s2r.demo.quickstart import quickstart

    quickstart(Path(args.out), workers=args.workers)
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("quickstart", help="synthetic data -> smoke runs -> held-out scores -> Table 4")
    sub.add_argument("--out", default="quickstart")
    sub.add_argument("--workers", type=int, default=2)
    sub.set_defaults(run=cmd_quickstart)
