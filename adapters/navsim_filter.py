"""NAVSIM's scene selection files: a SceneFilter yaml (or a token list) and a v2 two-stage split's
``reactive_all_mapping`` (the groups themselves: :mod:`lead_s2r.formats.navsim_two_stage`)."""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from lead_s2r.formats.navsim_two_stage import TwoStageGroup, parse_mapping
from lead_s2r_adapters.navsim_io import NavsimFormatError

#: NAVSIM SceneFilter defaults (navtrain / navtest): 4 history frames including the current one, 10 future frames.
DEFAULT_HISTORY, DEFAULT_FUTURE = 4, 10
#: SceneFilter fields that select v2 synthetic scenes (their union is converted).
SYNTHETIC_TOKEN_FIELDS = (
    "synthetic_scene_tokens",
    "reactive_synthetic_initial_tokens",
    "non_reactive_synthetic_initial_tokens",
)


@dataclass(frozen=True)
class SceneFilter:
    """The parts of NAVSIM's SceneFilter a conversion uses; None = not constrained by the filter."""

    name: str
    tokens: frozenset[str] | None = None
    log_names: frozenset[str] | None = None
    num_history_frames: int | None = None
    num_future_frames: int | None = None
    frame_interval: int | None = None
    has_route: bool = True
    include_synthetic: bool = False
    synthetic_tokens: frozenset[str] | None = None  # v2 synthetic (stage-2) scenes to convert; None = all
    last_token: str | None = None  # the list's last entry: where a file cut short at a line ends


def _text(path: Path) -> str:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise NavsimFormatError(f"{path}: cannot be read as text ({err})") from None


def _yaml(path: Path) -> Any:
    try:
        return yaml.safe_load(_text(path))
    except yaml.YAMLError as err:
        raise NavsimFormatError(f"{path}: not valid YAML ({' '.join(str(err).split())})") from None


def read_scene_filter(path: Path) -> SceneFilter:
    """A NAVSIM scene-filter yaml (``tokens``, ``log_names``, frame counts) or a text file of one token a line."""
    path = Path(path)
    if not path.is_file():
        raise NavsimFormatError(f"scene filter {path} does not exist")
    if path.suffix not in (".yaml", ".yml"):
        lines = [line.strip() for line in _text(path).splitlines()]
        listed = [t for t in lines if t and not t.startswith("#")]
        return SceneFilter(path.stem, tokens=frozenset(listed), last_token=listed[-1] if listed else None)
    config = _yaml(path) or {}
    if not isinstance(config, dict):
        raise NavsimFormatError(f"{path}: a scene filter must be a mapping")

    def optional(name: str, kind: type) -> Any:
        value = config.get(name)
        if value is not None and not isinstance(value, kind):
            raise NavsimFormatError(f"{path}: field {name!r} must be {kind.__name__}, got {value!r}")
        return value

    tokens, logs = optional("tokens", list), optional("log_names", list)
    history, future = optional("num_history_frames", int), optional("num_future_frames", int)
    interval = optional("frame_interval", int)
    synthetic = [optional(name, list) for name in SYNTHETIC_TOKEN_FIELDS]
    if interval is None:  # NAVSIM's SceneFilter: no frame_interval = back-to-back scenes of its own num_frames
        interval = (history or DEFAULT_HISTORY) + (future or DEFAULT_FUTURE)
    return SceneFilter(
        name=path.stem,
        tokens=None if tokens is None else frozenset(map(str, tokens)),
        last_token=str(tokens[-1]) if tokens else None,
        log_names=None if logs is None else frozenset(map(str, logs)),
        num_history_frames=history,
        num_future_frames=future,
        frame_interval=interval,
        has_route=bool(config.get("has_route", True)),
        include_synthetic=bool(config.get("include_synthetic_scenes", False)),
        synthetic_tokens=None
        if all(v is None for v in synthetic)
        else frozenset(str(t) for v in synthetic for t in v or []),
    )


def read_two_stage_mapping(path: Path) -> list[TwoStageGroup]:
    """``reactive_all_mapping`` of a NAVSIM v2 train/test-split yaml (e.g. ``navhard_two_stage.yaml``)."""
    if not path.is_file():
        raise NavsimFormatError(f"two-stage mapping {path} does not exist")
    config = _yaml(path) or {}
    raw = config.get("reactive_all_mapping") if isinstance(config, dict) else None
    if not isinstance(raw, list):
        raise NavsimFormatError(f"{path}: field 'reactive_all_mapping' must be a list of [orig, prev, pairs] entries")
    try:
        return parse_mapping(raw)
    except ValueError as err:
        raise NavsimFormatError(f"{path}: {err}") from None


def two_stage_roles(groups: list[TwoStageGroup]) -> dict[str, dict[str, Any]]:
    """token -> ``stage`` (1 or 2), ``two_stage_role`` and the token's ``two_stage_group`` [orig, prev, pairs]."""
    roles: dict[str, dict[str, Any]] = {}
    for group in groups:
        raw = [group.original, group.previous, [list(pair) for pair in group.pairs]]
        roles[group.original] = {"stage": 1, "two_stage_role": "original", "two_stage_group": raw}
        roles[group.previous] = {"stage": 1, "two_stage_role": "previous", "two_stage_group": raw}
        for now, before in group.pairs:
            roles[now] = {"stage": 2, "two_stage_role": "now", "two_stage_group": raw}
            roles[before] = {"stage": 2, "two_stage_role": "previous", "two_stage_group": raw}
    return roles
