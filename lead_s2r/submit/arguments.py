"""The arguments of ``lead-s2r submit`` (navsim, wod-e2e, --check), apart from cli.py to keep it one screen per verb."""

import argparse
from collections.abc import Callable
from typing import Any


def _boolean(value: str) -> bool:
    if value.lower() not in ("true", "false"):
        raise argparse.ArgumentTypeError(f"expected true or false, got {value!r}")
    return value.lower() == "true"


def add_submit_parser(verbs: Any, run: Callable[[argparse.Namespace], int]) -> None:
    """``lead-s2r submit``'s arguments (``run``: the verb's body in cli.py)."""
    sub = verbs.add_parser(
        "submit",
        help="write a NAVSIM or WOD-E2E leaderboard submission (validated first), or --check one",
        description="Steps for both leaderboards: docs/submitting.md.",
    )
    sub.add_argument("--check", metavar="FILE", help="re-read a written submission and report what it holds")
    sub.set_defaults(run=run, target=None)
    targets = sub.add_subparsers(dest="target", metavar="LEADERBOARD")

    navsim = targets.add_parser("navsim", help="submission.pkl for NAVSIM v1.1 (navtest) or v2 two-stage (navhard)")
    navsim.add_argument("--predictions", required=True, action="append", help="predictions.parquet; repeat per seed")
    navsim.add_argument("--data", required=True, nargs="+", help="the converted split (navtest, navhard_two_stage)")
    navsim.add_argument("--out", required=True, help="submission.pkl (the name the leaderboard expects)")
    navsim.add_argument("--two-stage", action="store_true", help="v2: first- and second-stage predictions")
    for option in ("team", "authors", "email", "institution", "country"):
        navsim.add_argument(f"--{option}", required=True)

    wod = targets.add_parser("wod-e2e", help="E2EDChallengeSubmission shards and the tar.gz to upload")
    wod.add_argument("--predictions", required=True)
    wod.add_argument("--data", required=True, nargs="+", help="the converted WOD-E2E folder(s)")
    wod.add_argument("--out", required=True, help="folder for the shards; OUT.tar.gz is written beside it")
    wod.add_argument("--split", default="test", help="converted split to cover (default: test)")
    wod.add_argument("--shards", type=int, default=1)
    wod.add_argument("--account", required=True, help="the email registered at waymo.com/open")
    wod.add_argument("--method", required=True, help="unique method name (the leaderboard keeps its latest result)")
    wod.add_argument("--authors", required=True, nargs="+")
    wod.add_argument("--num-params", required=True, help="model size: an integer and K/M/B/T, e.g. 60M")
    wod.add_argument("--pretrained", required=True, type=_boolean, help="true if public LLM/VLM pre-training was used")
    wod.add_argument("--public-models", nargs="*", default=[], help="names of those public models")
    wod.add_argument("--affiliation", default="")
    wod.add_argument("--description", default="")
    wod.add_argument("--method-link", default="")
