"""``lead-s2r closed-loop``: offline checks of a run before it drives."""

import argparse
from typing import Any

from lead_s2r.errors import UserError


def cmd_closed_loop_check(args: argparse.Namespace) -> int:
    from lead_s2r.closed_loop.check import check_run
    from lead_s2r.closed_loop.checkpoint import UnsupportedCheckpoint

    try:
        result = check_run(args.path, ticks=args.ticks)
    except (UnsupportedCheckpoint, FileNotFoundError) as err:
        raise UserError(f"closed-loop check: {err}") from None
    print("\n".join(result.lines()))
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("closed-loop", help="offline checks of a run before a CARLA evaluation")
    checks = sub.add_subparsers(dest="check", required=True, metavar="CHECK")
    sub = checks.add_parser(
        "check", help="the agent's setup, sensors and a few ticks on synthetic sensor data, no CARLA server"
    )
    sub.add_argument("path", metavar="RUN", help="run folder (runs/carla/<name>/seed<k>), checkpoint, or agent YAML")
    sub.add_argument("--ticks", type=int, default=5, help="ticks to drive (the first brakes, as in a real route)")
    sub.set_defaults(run=cmd_closed_loop_check)
