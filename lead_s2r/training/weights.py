"""``init_from``: start fine-tuning from pre-trained weights, loading every tensor whose name and shape match.

Besides our Lightning checkpoints, a bare LEAD checkpoint file (``model_0030.pth``, LEAD's ``TFv6.state_dict()``) or
a LEAD checkpoint folder (``config.json`` + one ``model*.pth``) initialises a
:class:`~lead_s2r.models.lead_driver.LeadDriver`: its keys are LEAD's, under the driver's ``network.``. From a folder
(or one weight file in it) the report also names the config fields where the two networks differ (LEAD's CARLA TFv6
fine-tuned on WOD-E2E: ``LTF``, the target dataset, ...), which is why heads are new, dropped or reshaped.
"""

from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import nn

from lead_s2r.errors import UserError
from lead_s2r.formats import torch_file
from lead_s2r.models.lead import read_config, weight_files
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver

#: Prefixes stripped from checkpoint keys: the LightningModule attribute and torch.compile's wrapper.
PREFIXES = ("model.", "_orig_mod.")


@dataclass
class LoadReport:
    """What a non-strict load did; new heads show up as ``missing``, dropped ones as ``unexpected``."""

    loaded: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)
    mismatched: list[str] = field(default_factory=list)
    config_changes: dict[str, tuple[object, object]] = field(default_factory=dict)

    def summary(self) -> str:
        lines = [f"init_from: loaded {len(self.loaded)} tensors"]
        for name in ("missing", "unexpected", "mismatched"):
            keys = getattr(self, name)
            if keys:
                lines.append(f"  {name} ({len(keys)}): {', '.join(_roots(keys))}")
        if self.config_changes:
            changes = (f"{k} {old!r} -> {new!r}" for k, (old, new) in self.config_changes.items())
            lines.append(f"  LEAD config changes: {', '.join(changes)}")
        return "\n".join(lines)


class CheckpointNotFound(UserError, FileNotFoundError):
    """A path that is neither a checkpoint file nor a run folder holding one."""


def find_checkpoint(path: str | Path) -> Path:
    """``path`` itself if it is a file; in a run folder ``checkpoints/last.ckpt``, ``last.ckpt``, else the newest
    ``*.ckpt`` below it."""
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        raise CheckpointNotFound(f"{path}: no such checkpoint file or run folder")
    for candidate in (path / "checkpoints" / "last.ckpt", path / "last.ckpt"):
        if candidate.is_file():
            return candidate
    found = sorted(path.rglob("*.ckpt"), key=lambda p: p.stat().st_mtime)
    if not found:
        raise CheckpointNotFound(
            f"{path}: no checkpoint (neither checkpoints/last.ckpt nor any *.ckpt below it); pass a checkpoint file "
            "or a run folder of `lead-s2r fit`"
        )
    return found[-1]


def _roots(keys: list[str], depth: int = 2) -> list[str]:
    """Collapse parameter names to their first ``depth`` components (after a LEAD driver's ``network.``)."""
    return sorted({".".join(k.removeprefix("network.").split(".")[:depth]) for k in keys})


def config_changes(old: LeadConfig, new: LeadConfig) -> dict[str, tuple[object, object]]:
    """LEAD config fields (and the target dataset) that differ between a checkpoint's network and ours."""
    before, after = asdict(old), asdict(new)
    changes = {k: (before[k], after[k]) for k in after if before[k] != after[k]}
    if old.target_dataset != new.target_dataset:
        changes["target_dataset"] = (old.target_dataset.name, new.target_dataset.name)
    return changes


def _strip(key: str) -> str:
    while key.startswith(PREFIXES):  # in any order, as often as they are nested
        key = next(key.removeprefix(prefix) for prefix in PREFIXES if key.startswith(prefix))
    return key


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """Tensors of a Lightning checkpoint (``state_dict`` entry) or a plain state dict, keys without prefixes."""
    path = Path(path)
    if path.is_dir():  # a LEAD checkpoint folder: its one weight file (an ensemble's must be told apart by the user)
        files = weight_files(path)
        if len(files) > 1:
            raise UserError(
                f"init_from: {path} holds {len(files)} weight files (an ensemble); name one, e.g. {files[0]}"
            )
        path = files[0]
    if not path.is_file():
        raise UserError(f"init_from: no checkpoint at {path}; give a .ckpt, a LEAD model*.pth or a LEAD folder")
    ckpt = torch_file.load(path)
    state = ckpt.get("state_dict", ckpt) if isinstance(ckpt, dict) else None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise UserError(f"init_from: {path} holds no state dict of tensors (looked at 'state_dict' and the top level)")
    return {_strip(k): v for k, v in state.items()}


def load_matching(model: nn.Module, path: str | Path) -> LoadReport:
    """Copy every checkpoint tensor whose name and shape match ``model``'s; report the rest."""
    source = read_state_dict(path)
    if isinstance(model, LeadDriver) and not any(k.startswith("network.") for k in source):
        source = {f"network.{k}": v for k, v in source.items()}  # a bare LEAD state_dict
    target = model.state_dict()
    report = LoadReport()
    matched = {}
    for key, value in source.items():
        if key not in target:
            report.unexpected.append(key)
        elif target[key].shape != value.shape:
            report.mismatched.append(key)
        else:
            matched[key] = value
            report.loaded.append(key)
    report.missing = [k for k in target if k not in source]
    if not matched:
        raise UserError(no_match_message(path, source, target))
    model.load_state_dict(matched, strict=False)
    folder = Path(path) if Path(path).is_dir() else Path(path).parent
    if isinstance(model, LeadDriver) and (folder / "config.json").is_file():  # a LEAD folder, or one file of it
        report.config_changes = config_changes(read_config(folder), model.config)
    return report


def no_match_message(path: str | Path, source: dict[str, torch.Tensor], target: dict[str, torch.Tensor]) -> str:
    """Why ``init_from`` would start from random weights: the names (or shapes) of the file's tensors and the
    model's, by their first component; the usual cause is a checkpoint of another model or a wrapper's prefix."""
    depth = 2 if len({key.split(".")[0] for key in (*source, *target)}) == 1 else 1  # a wrapper's shared first part
    theirs, ours = (sorted({".".join(key.split(".")[:depth]) + "." for key in keys}) for keys in (source, target))
    if set(source) & set(target):
        return f"init_from: {path}: no tensor matches the model's shape (another model size?); model prefixes {ours}"
    shown = theirs[:8] + ["..."] * (len(theirs) > 8)
    return (
        f"init_from: {path}: no tensor name matches the model; the model expects names under {ours}, the file has"
        f" {shown} (after dropping {', '.join(map(repr, PREFIXES))}); pass the checkpoint of this model"
    )
