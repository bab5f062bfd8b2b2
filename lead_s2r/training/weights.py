"""``init_from``: start fine-tuning from pre-trained weights, loading every tensor whose name and shape match.

Besides our Lightning checkpoints, a bare LEAD checkpoint file (``model_0030.pth``, LEAD's ``TFv6.state_dict()``)
initialises a :class:`~lead_s2r.models.lead_driver.LeadDriver`: its keys are LEAD's, under the driver's ``network.``.
"""

from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn

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

    def summary(self) -> str:
        lines = [f"init_from: loaded {len(self.loaded)} tensors"]
        for name in ("missing", "unexpected", "mismatched"):
            keys = getattr(self, name)
            if keys:
                lines.append(f"  {name} ({len(keys)}): {', '.join(_roots(keys))}")
        return "\n".join(lines)


def _roots(keys: list[str], depth: int = 2) -> list[str]:
    """Collapse parameter names to their first ``depth`` components, for a readable report."""
    return sorted({".".join(k.split(".")[:depth]) for k in keys})


def _strip(key: str) -> str:
    changed = True
    while changed:
        changed = False
        for prefix in PREFIXES:
            if key.startswith(prefix):
                key, changed = key[len(prefix) :], True
    return key


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """Tensors of a Lightning checkpoint (``state_dict`` entry) or a plain state dict, keys without prefixes."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"init_from: no checkpoint at {path}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises UnpicklingError and friends for non-tensor payloads
        raise ValueError(f"init_from: {path} is not a weights-only torch checkpoint: {err}") from err
    state = ckpt.get("state_dict", ckpt) if isinstance(ckpt, dict) else None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"init_from: {path} holds no state dict of tensors (looked at 'state_dict' and the top level)")
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
    model.load_state_dict(matched, strict=False)
    return report
