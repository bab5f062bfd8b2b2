"""``lead-s2r submit``: NAVSIM and WOD-E2E leaderboard files, validated before anything is written, or ``--check``."""

import argparse
import json
from pathlib import Path
from typing import Any

from lead_s2r.errors import UserError


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


def _boolean(value: str) -> bool:
    if value.lower() not in ("true", "false"):
        raise argparse.ArgumentTypeError(f"expected true or false, got {value!r}")
    return value.lower() == "true"


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser(
        "submit",
        help="write a NAVSIM or WOD-E2E leaderboard submission (validated first), or --check one",
        description="Steps for both leaderboards: docs/submitting.md.",
    )
    sub.add_argument("--check", metavar="FILE", help="re-read a written submission and report what it holds")
    sub.set_defaults(run=cmd_submit, target=None)
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
