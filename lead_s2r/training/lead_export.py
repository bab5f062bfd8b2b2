"""``lead-s2r export-lead RUN --out FOLDER``: a run whose network is LEAD's architecture
(:class:`~lead_s2r.models.lead_driver.LeadDriver`) back to a LEAD checkpoint folder (config.json + model_0000.pth)
that LEAD's own inference loads with ``strict=True``."""

from pathlib import Path

from lead_s2r.errors import UserError
from lead_s2r.formats import torch_file
from lead_s2r.models.lead import export_checkpoint
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.models.lead_tfv6 import LeadTFv6
from lead_s2r.training.module import DrivingModule


def run_checkpoint(run: Path) -> Path:
    """A ``.ckpt`` file as given, else ``<run>/checkpoints/last.ckpt``, else the run's newest checkpoint."""
    if run.is_file():
        return run
    folder = run / "checkpoints"
    if (folder / "last.ckpt").is_file():
        return folder / "last.ckpt"
    found = sorted(folder.glob("*.ckpt"), key=lambda p: p.stat().st_mtime)
    if not found:
        raise UserError(f"{run}: no checkpoint (a .ckpt file, or a run folder with checkpoints/*.ckpt)")
    return found[-1]


def export_run(run: Path, out: Path) -> Path:
    checkpoint = run_checkpoint(run)
    torch_file.load(checkpoint, zip_only=True)  # damage, or the removed network, named in one line
    module = DrivingModule.load_from_checkpoint(checkpoint, map_location="cpu")
    model = module.model
    if not isinstance(model, LeadDriver) or not isinstance(model.network, LeadTFv6):
        raise UserError(
            f"{checkpoint}: its network is {type(model).__name__}, not one LEAD network; only runs trained with "
            "lead_s2r.models.lead_driver.LeadDriver export to LEAD's format"
        )
    return export_checkpoint(model.network, out)
