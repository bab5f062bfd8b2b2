"""``lead-s2r export-lead RUN --out FOLDER``: a run whose network is LEAD's architecture
(:class:`~lead_s2r.models.lead_driver.LeadDriver`) back to a LEAD checkpoint folder (config.json + model_0000.pth)
that LEAD's own inference loads with ``strict=True`` and runs to our outputs.

LEAD's loader (``TrainingConfig(json.load(config.json))``) takes class attributes and "overridable" properties from the
file, but recomputes plain properties from its own rules and ignores keys it does not know. Our extensions of its config
(:data:`LEAD_DERIVES`) are such fields, so a network that sets one to a value LEAD's rules do not give cannot be
represented: LEAD would build another shape (its strict load fails: one target point's ``status_pos_embedding``,
``camera_tile_size``'s ``pos_emb``, 12 waypoints' ``query``) or, worse, load and mean something else (waypoints 0.25 s
apart read as 0.5 s apart, or a toy ``trajectory_scale``'s outputs read as metres). Such a run is refused in one line
naming the field, before anything is written; so is a WOD-E2E network, which LEAD's code (4489176) cannot build at all.
Where the values agree, our fields are written too (``waypoint_interval_s``, ``camera_tile_size``): LEAD ignores keys it
does not know, and our loader reads them back. Checked with LEAD's own loader and forward on every configuration of
tests/data/lead_tfv6/export_*.pt (README there).

The run's ``.ckpt`` is read weights-only with its zip CRCs checked (:mod:`lead_s2r.formats.torch_file`): a flipped
bit or a cut file is a one-line error, never a silent export of other weights.
"""

from dataclasses import replace
from pathlib import Path
from typing import Any

from lead_s2r.errors import UserError
from lead_s2r.formats import torch_file
from lead_s2r.models.lead import export_checkpoint
from lead_s2r.models.lead_config import TOY_SCALES, LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.models.lead_tfv6 import LeadTFv6
from lead_s2r.training.weights import find_checkpoint

#: Our config fields that LEAD's loader never reads from config.json (plain properties it derives, or fields it does
#: not have), each with the attribute that holds its effect on the network.
LEAD_DERIVES = {
    "use_previous_tp": "use_previous_tp",
    "use_next_tp": "use_next_tp",
    "num_way_points_prediction": "num_way_points_prediction",
    "waypoint_interval_s": "waypoint_interval_s",
    "camera_tile_size": "camera_tile",
}
#: Our keys in an exported config.json that LEAD ignores (they hold what LEAD's rules derive).
OUR_KEYS = ("waypoint_interval_s", "camera_tile_size", *TOY_SCALES)


def check_lead_reads(config: LeadConfig, source: Path) -> None:
    """A :class:`UserError` naming the first field of ``config`` (the network of ``source``) LEAD cannot represent."""
    if config.is_wod:
        raise UserError(
            f"{source}: use_waymo_e2e_data is true, and LEAD's code cannot build a WOD-E2E network (its camera "
            "calibration imports a function missing from its public code); nothing written"
        )
    for name in TOY_SCALES:
        if getattr(config, name) != 1.0:
            raise UserError(
                f"{source}: {name}={getattr(config, name)!r} is our toy scale, which LEAD's network does not have "
                "(LEAD's is 1.0), so LEAD cannot load this network as trained; nothing written"
            )
    as_lead_reads = replace(config, **dict.fromkeys(LEAD_DERIVES))  # None: LEAD's rule decides
    for field, effect in LEAD_DERIVES.items():
        ours, leads = getattr(config, effect), getattr(as_lead_reads, effect)
        if ours != leads:
            raise UserError(
                f"{source}: {field}={getattr(config, field)!r} is our extension; LEAD ignores the field and derives "
                f"{leads!r}, so LEAD cannot load this network as trained; nothing written"
            )


def read_network(checkpoint: Path) -> LeadTFv6:
    """The LEAD network of a ``DrivingModule`` checkpoint, rebuilt from its ``hyper_parameters`` (as LightningCLI
    saved them) and loaded strictly; anything else is a :class:`UserError` naming the file."""
    from lightning.pytorch.cli import instantiate_module  # Lightning is only needed here

    from lead_s2r.training.module import DrivingModule

    saved = torch_file.load(checkpoint)
    hparams = saved.get("hyper_parameters") if isinstance(saved, dict) else None
    model: Any = hparams.get("model") if isinstance(hparams, dict) else None
    class_path = model.get("class_path") if isinstance(model, dict) else "not named in its hyper_parameters"
    if class_path != f"{LeadDriver.__module__}.{LeadDriver.__name__}" or not isinstance(saved.get("state_dict"), dict):
        raise UserError(
            f"{checkpoint}: its network is {class_path}, not one LEAD network; only runs trained with "
            "lead_s2r.models.lead_driver.LeadDriver export to LEAD's format"
        )
    arguments = {k: v for k, v in hparams.items() if k != "_instantiator"}
    module = instantiate_module(DrivingModule, {**arguments, "init_from": None, "compile": False})
    try:
        module.load_state_dict(saved["state_dict"], strict=True)
    except RuntimeError as err:
        reason = " ".join(str(err).split())[:300]
        raise UserError(f"{checkpoint}: its weights do not fit the LeadDriver it describes ({reason})") from None
    network = module.model.network
    if not isinstance(network, LeadTFv6):
        raise UserError(f"{checkpoint}: holds an ensemble of LEAD networks; export one (model.pattern) instead")
    return network


def export_run(run: Path, out: Path) -> Path:
    """Export the run's checkpoint to ``out`` (config.json + model_0000.pth), or refuse before writing anything."""
    checkpoint = find_checkpoint(run)
    network = read_network(checkpoint)
    check_lead_reads(network.config, checkpoint)
    return export_checkpoint(network.eval(), out)
