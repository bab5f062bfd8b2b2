"""LEAD's checkpoint folders in and out: ``config.json`` + ``model*.pth`` (bare ``TFv6.state_dict()`` files).

- :func:`load_checkpoint` reads a folder as LEAD's ``OpenLoopInference`` does: the config through LEAD's rules
  (:meth:`LeadConfig.from_json`), one network per matching file, each loaded strictly; several files make an ensemble.
  A damaged file is an error naming it (:func:`read_weights` checks the archive's CRCs, which torch does not).
- :func:`export_checkpoint` writes a folder LEAD's own loader reads with ``strict=True``.
- :func:`loss`, :func:`optimizer` and :func:`scheduler` train it as LEAD's Trainer does (:mod:`.lead_loss`).
"""

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from lead_s2r.errors import UserError
from lead_s2r.files import write_atomically, write_text
from lead_s2r.formats import torch_file
from lead_s2r.models import lead_loss
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_loss import loss as loss  # re-exported: LEAD's training computation
from lead_s2r.models.lead_loss import scheduler as scheduler
from lead_s2r.models.lead_planner import expected_speed
from lead_s2r.models.lead_tfv6 import LeadTFv6

#: Planner outputs averaged over ensemble members in every mode, as LEAD's ``OpenLoopInference.ensemble`` does
#: (target-speed logits averaged; the scalar speed recomputed from them).
AVERAGED = ("pred_future_waypoints", "pred_route", "pred_headings", "pred_target_speed_distribution")
#: Semantic maps LEAD merges in CARLA leaderboard mode only: background channel min, the other channels max.
MAX_MERGED = ("pred_bev_semantic", "pred_semantic")


class LeadEnsemble(nn.Module):
    """Several LEAD networks with one config; ``forward`` merges their outputs as LEAD's open-loop inference
    (``OpenLoopInference.ensemble``, lead/inference/open_loop_inference.py at 4489176), per mode:

    - always: :data:`AVERAGED` (LEAD returns the speed logits' softmax; we keep logits, as a single network does);
    - CARLA leaderboard mode only: :data:`MAX_MERGED`, depth averaged; LEAD decodes each member's boxes and merges them
      by NMS, post-processing we do not run here, so the CARLA CenterNet maps are averaged instead (what box consumers
      such as the agent's stop-sign slowdown read; not LEAD's merge);
    - never: NAVSIM's BEV and box maps, CARLA's maps outside leaderboard mode, the radar detector's queries.

    LEAD's brake override (speed 0 when the 0 m/s class's probability is over ``brake_threshold``) belongs to its
    driving config, not to the merge.
    """

    def __init__(self, members: list[LeadTFv6]) -> None:
        super().__init__()
        self.members = nn.ModuleList(members)
        self.config = members[0].config

    def forward(self, data: dict[str, Tensor]) -> dict[str, Tensor]:
        outputs = [member(data) for member in self.members]
        merged = {key: torch.stack([o[key] for o in outputs]).mean(0) for key in AVERAGED if key in outputs[0]}
        if "pred_target_speed_distribution" in merged:
            merged["pred_target_speed_scalar"] = expected_speed(merged["pred_target_speed_distribution"])
        if self.config.carla_leaderboard_mode:
            for key in MAX_MERGED:
                if key in outputs[0]:
                    stacked = torch.stack([o[key] for o in outputs])
                    merged[key] = torch.cat([stacked[:, :, :1].min(0).values, stacked[:, :, 1:].max(0).values], 1)
            for key in outputs[0]:
                if key == "pred_depth" or key.startswith("pred_bounding_box."):
                    merged[key] = torch.stack([o[key] for o in outputs]).mean(0)
        return merged


def model_from_config(config: dict[str, Any]) -> LeadTFv6:
    """A randomly initialised LEAD network for a config.json dict (LEAD's defaults for every key it lacks)."""
    return LeadTFv6(LeadConfig.from_json(config))


def read_config(folder: Path) -> LeadConfig:
    path = folder / "config.json"
    if not path.is_file():
        raise UserError(f"{folder}: no config.json; give a LEAD checkpoint folder (config.json + model*.pth)")
    try:
        values = json.loads(path.read_bytes())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserError(f"{path}: not valid JSON ({err})") from err
    if not isinstance(values, dict):
        raise UserError(f"{path}: expected a JSON object of LEAD TrainingConfig fields")
    try:
        return LeadConfig.from_json(values)
    except UserError as err:  # LeadConfig names the field as config.json's; the file is this folder's
        raise UserError(f"{path}: {str(err).removeprefix('config.json: ')}") from err


def weight_files(folder: Path, pattern: str = "model*.pth") -> list[Path]:
    """The weight files of a LEAD checkpoint folder, sorted (several = an ensemble's members)."""
    files = sorted(folder.glob(pattern))
    if not files:
        raise UserError(f"{folder}: no file matches {pattern!r}; LEAD names its weights model_<epoch>.pth")
    return files


def load_checkpoint(folder: str | Path, pattern: str = "model*.pth") -> nn.Module:
    """LEAD's checkpoint folder -> one network in eval mode, or a :class:`LeadEnsemble` when several files match."""
    folder = Path(folder)
    config = read_config(folder)
    members = []
    for file in weight_files(folder, pattern):
        try:
            model = LeadTFv6(config)
        except ValueError as err:  # a value of its JSON type that a layer refuses (a dropout probability of 7)
            raise UserError(f"{folder / 'config.json'}: LEAD's network cannot be built from it ({err})") from None
        state = read_weights(file)
        try:
            model.load_state_dict(state, strict=True)
        except RuntimeError as err:
            raise UserError(f"{file}: does not match the architecture config.json describes: {err}") from err
        members.append(model.eval())
    return members[0] if len(members) == 1 else LeadEnsemble(members).eval()


def read_weights(file: Path) -> dict[str, Tensor]:
    """The state_dict of one ``model*.pth``, its archive's CRCs checked (:mod:`lead_s2r.formats.torch_file`)."""
    state = torch_file.load(file)
    if not isinstance(state, dict):
        raise UserError(f"{file}: holds a {type(state).__name__}, not the state_dict LEAD saves")
    return state


def forward(model: nn.Module, inputs: dict[str, Tensor]) -> dict[str, Tensor]:
    """LEAD's input dict (x forward, y right) -> its ``Prediction`` fields as a flat dict, inference mode (float32)."""
    with torch.inference_mode():
        return model(inputs)


def optimizer(model: nn.Module, config: LeadConfig | Mapping | str | Path | None = None) -> torch.optim.AdamW:
    """LEAD's optimizer (:func:`lead_loss.optimizer`) with the settings of ``config``: a :class:`LeadConfig`, a
    config.json dict, the path of a config.json or of its checkpoint folder; default: the model's."""
    if isinstance(config, str | Path):
        path = Path(config)
        config = read_config(path if path.is_dir() else path.parent)
    return lead_loss.optimizer(model, config)


def export_checkpoint(model: nn.Module, folder: str | Path) -> Path:
    """Write ``config.json`` + ``model_0000.pth`` (contiguous float32 tensors, no wrapper, no prefix)."""
    if not isinstance(model, LeadTFv6):
        raise TypeError(f"export_checkpoint takes one LeadTFv6 network, got {type(model).__name__}")
    folder = Path(folder)
    state = {k: v.detach().cpu().contiguous().clone() for k, v in model.state_dict().items()}
    write_text(folder / "config.json", json.dumps(model.config.to_json(), indent=1))
    write_atomically(folder / "model_0000.pth", lambda partial: torch.save(state, partial))
    return folder
