"""Verbs around trained runs apart from LightningCLI's own (fit / validate / test / predict): ``export-lead``."""

import argparse
from pathlib import Path
from typing import Any


def cmd_export_lead(args: argparse.Namespace) -> int:
    from lead_s2r.training.lead_export import OUR_KEYS, export_run

    folder = export_run(Path(args.run_dir), Path(args.out))
    print(
        f"wrote {folder} (config.json + model_0000.pth, LEAD's format; LEAD ignores our keys {', '.join(OUR_KEYS)}, "
        "which hold what its rules derive)"
    )
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("export-lead", help="a run trained with LEAD's architecture -> a LEAD checkpoint folder")
    sub.add_argument("run_dir", metavar="RUN", help="run folder (its checkpoints/last.ckpt) or a .ckpt file")
    sub.add_argument("--out", required=True, help="folder for config.json + model_0000.pth")
    sub.set_defaults(run=cmd_export_lead)
