"""A trained run -> the driving network, its configuration and the CARLA camera rig it was trained for.

No second config format: a checkpoint of ``DrivingModule`` describes its network in its ``hyper_parameters`` (class path
and typed config, see :mod:`lead_s2r.training.module`), so a ``.ckpt`` copied anywhere drives alone. Checkpoints written
before that describe no network; for them the run's ``config.yaml`` that ``lead-s2r fit`` (LightningCLI) saved is read
instead. A checkpoint with neither, or whose weights do not fit its description, is refused with what to do, as is a
model that cannot drive a CARLA route: one without an output grid for the source, or one that reads no route target
points (an LTFv6 NAVSIM model, which builds no target-point encoder: it would not know where to turn). LEAD's users hit
exactly these silent mismatches between configs and weights; here they are errors at load time.

A LEAD checkpoint folder (``config.json`` + ``model*.pth``, e.g. LEAD's released CARLA TFv6; several matching files:
LEAD's ensemble) drives too, as a :class:`~lead_s2r.models.lead_driver.LeadDriver`.

The camera rig is not stored by training either; it follows from the model's input: the LEAD rig whose stitched
strip (after the model's ``vertical_fov_deg`` crop, the same :func:`~lead_s2r.data.camera_layout.camera_layout`
training used) has the aspect of ``image_size`` (3 cameras 3:1, 6 cameras 6:1, the wide camera 8:3, NAVSIM's 64:9).
"""

import math
from pathlib import Path
from typing import Any

import yaml
from torch import nn

from lead_s2r.data.camera_layout import calibration, camera_layout, tiles_at
from lead_s2r.formats import torch_file
from lead_s2r.formats.carla_rig import CAMERA_RIGS, MOSAIC_ID, camera_calibration
from lead_s2r.models.input_spec import InputSpec, input_spec
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.training.weights import find_checkpoint

#: The file LightningCLI writes the resolved run configuration to.
CONFIG_NAME = "config.yaml"
#: The file that marks a LEAD checkpoint folder.
LEAD_CONFIG_NAME = "config.json"


class UnsupportedCheckpoint(ValueError):
    """A checkpoint this agent cannot drive with; the message says why and what to do."""


def saved_config(checkpoint: Path) -> Path:
    """LightningCLI's ``config.yaml`` of the run a checkpoint belongs to: beside it or up to two folders up (the run
    folder of ``<run>/checkpoints/last.ckpt``), or in the newest ``lightning_logs/version_*`` there."""
    for folder in list(checkpoint.resolve().parents)[:3]:
        logged = sorted(folder.glob(f"lightning_logs/version_*/{CONFIG_NAME}"), key=lambda p: p.stat().st_mtime)
        for candidate in [folder / CONFIG_NAME, *logged[::-1]]:
            if candidate.is_file():
                return candidate
    raise UnsupportedCheckpoint(
        f"{checkpoint}: its hyper_parameters describe no network (a checkpoint written before they did) and no "
        f"{CONFIG_NAME} (the configuration `lead-s2r fit` saves in its run folder) is beside it or in its run "
        "folder, so the network cannot be rebuilt; pass the run folder of `lead-s2r fit`"
    )


def module_arguments(checkpoint: Path, saved: dict[str, Any]) -> tuple[dict[str, Any], str]:
    """``DrivingModule`` arguments (``_class_path`` for a subclass) of a loaded checkpoint and where they come from:
    its own ``hyper_parameters`` when they describe the network, else the run's ``config.yaml`` (older checkpoints)."""
    hparams = saved.get("hyper_parameters") or {}
    if isinstance(hparams.get("model"), dict):
        return {k: v for k, v in hparams.items() if k != "_instantiator"}, str(checkpoint)
    config_path = saved_config(checkpoint)
    section = (yaml.safe_load(config_path.read_text()) or {}).get("model")
    if not isinstance(section, dict) or "model" not in section:
        raise UnsupportedCheckpoint(f"{config_path}: no 'model.model' entry (the network's class and config)")
    if "class_path" in section:  # a DrivingModule subclass
        section = {"_class_path": section["class_path"], **section.get("init_args", {})}
    return section, str(config_path)


def load_model(checkpoint: Path, device: str = "cpu") -> nn.Module:
    """The network of a ``DrivingModule`` checkpoint, rebuilt from its own description (or its run's saved config)."""
    from lightning.pytorch.cli import instantiate_module  # Lightning is only needed here

    from lead_s2r.training.module import DrivingModule

    saved = torch_file.load(checkpoint)
    if not isinstance(saved, dict):
        raise UnsupportedCheckpoint(f"{checkpoint}: holds a {type(saved).__name__}, not a Lightning checkpoint")
    arguments, described_by = module_arguments(checkpoint, saved)
    module = instantiate_module(DrivingModule, {**arguments, "init_from": None, "compile": False})
    try:
        module.load_state_dict(saved["state_dict"])
    except (KeyError, RuntimeError) as err:
        raise UnsupportedCheckpoint(f"{checkpoint}: its weights do not fit the model of {described_by}: {err}") from err
    return module.model.to(device).eval()


def load_driving_model(path: str | Path, pattern: str, device: str) -> tuple[nn.Module, Path]:
    """The network to drive with (eval mode, on ``device``) and the file or folder it came from: a LEAD checkpoint
    folder's files matching ``pattern``, else the checkpoint :func:`find_checkpoint` picks."""
    folder = Path(path)
    if (folder / LEAD_CONFIG_NAME).is_file():
        return LeadDriver(checkpoint=str(folder), pattern=pattern).to(device).eval(), folder
    checkpoint = find_checkpoint(folder)
    return load_model(checkpoint, device), checkpoint


def family_spec(model: nn.Module, path: Path, where: str) -> InputSpec:
    """What a TFv6-family model reads; :class:`UnsupportedCheckpoint` for any other (the ego MLP reads no sensor)."""
    config = getattr(model, "config", None)
    if not isinstance(config, LeadConfig):
        raise UnsupportedCheckpoint(
            f"{path}: {type(model).__name__} is not a TransFuser-family model (no LeadConfig); only "
            f"camera(+LiDAR) models with a planning decoder can drive {where}"
        )
    return input_spec(config)


def check_drivable(model: nn.Module, source: str, path: Path) -> InputSpec:
    """What the model reads, or :class:`UnsupportedCheckpoint` if it cannot drive a CARLA route as ``source``."""
    spec = family_spec(model, path, "in CARLA")
    if source not in spec.trajectory_grids or "waypoints" not in model.tasks(source):
        raise UnsupportedCheckpoint(
            f"{path}: the model plans for no source {source!r} (output grids: {sorted(spec.trajectory_grids)}); set "
            "the agent's source to one it was trained on"
        )
    if not getattr(model, "reads_target_points", False):
        raise UnsupportedCheckpoint(
            f"{path}: the model reads no route target points (e.g. an LTFv6 NAVSIM model), so it cannot follow a "
            "CARLA route; train a CARLA leaderboard model (LEAD's use_tp)"
        )
    return spec


def strip_aspect(rig: str, config: InputSpec) -> float:
    """Width / height of a rig's stitched strip as the training transform lays it out for ``config``."""
    cameras = CAMERA_RIGS[rig]
    meta = {"cameras": camera_calibration(rig)}
    shape = (cameras[0].stored_height, sum(camera.width for camera in cameras))
    tiles = tiles_at(calibration(meta, MOSAIC_ID), shape)
    layout = camera_layout(((shape, tiles),), tuple(config.image_size), config.vertical_fov_deg)
    return layout.strip[1] / layout.strip[0]


def rig_for(config: InputSpec) -> str:
    """The LEAD rig whose strip aspect is nearest (in log ratio) to the model's ``image_size``."""
    height, width = config.image_size
    return min(CAMERA_RIGS, key=lambda rig: abs(math.log(strip_aspect(rig, config) * height / width)))
