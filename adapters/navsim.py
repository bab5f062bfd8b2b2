"""NAVSIM / OpenScene -> schema v1: one sample per scene token, read from the files NAVSIM's download scripts leave.

``<src>/navsim_logs/<split>/<log>.pkl`` (a plain pickle of per-frame dicts at 2 Hz, read with a restricted unpickler),
``<src>/sensor_blobs/<split>/<log>/...`` (JPEGs and nuPlan binary PCDs) and, with ``maps``, nuPlan GeoPackage maps
(:mod:`lead_s2r_adapters.navsim_map`). A scene is NAVSIM's window of ``num_history_frames`` frames (the last is the
current frame, whose token is the scene token) plus ``num_future_frames``. Each worker loads a log pickle once and a
map once per location. This module lists the work and checks the scene filter; the samples are built by
:mod:`lead_s2r_adapters.navsim_log` (logged scenes) and :mod:`lead_s2r_adapters.navsim_synthetic` (NAVSIM v2 synthetic
scenes). Layout of every field: ``docs/datasets/navsim.md``.
"""

import statistics
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from lead_s2r.errors import UserError, listing
from lead_s2r.registry import Adapter, LogRef
from lead_s2r_adapters import navsim_map
from lead_s2r_adapters.navsim_filter import (
    DEFAULT_FUTURE,
    DEFAULT_HISTORY,
    SceneFilter,
    read_scene_filter,
    read_two_stage_mapping,
    two_stage_roles,
)
from lead_s2r_adapters.navsim_io import CAMERAS, NavsimFormatError, load_log, required
from lead_s2r_adapters.navsim_log import LogScenes
from lead_s2r_adapters.navsim_synthetic import SyntheticScene

SYNTHETIC = "synthetic_scene"
#: v2 two-stage split folders (``navhard_two_stage``, ...): logs, sensors and synthetic scenes side by side.
TWO_STAGE_LOGS = "openscene_meta_datas"
TWO_STAGE_SENSORS = "sensor_blobs"
TWO_STAGE_SYNTHETIC = "synthetic_scene_pickles"


class NavsimAdapter(Adapter):
    """OpenScene logs (+ sensor blobs, + nuPlan maps with ``maps``) -> one schema v1 sample per scene token.

    ``split`` picks a folder of ``navsim_logs`` (``trainval``, ``test``, ``mini``; default all); ``scene_filter`` a
    NAVSIM scene-filter yaml or token list (its frame counts apply unless given here); ``maps`` the nuPlan maps root,
    which adds ``scoring`` and ``bev_semantic``; ``two_stage_mapping`` a NAVSIM v2 train/test-split yaml with
    ``reactive_all_mapping`` (navhard two-stage): every sample then records its stage and group in
    ``meta.extras.navsim`` and info.json keeps the whole mapping; ``tag_filters`` scene filters (comma-separated paths)
    that name subsets: a sample whose token one of them lists gets the tag ``scene_filter:<its file stem>`` (NAVSIM's
    format has no field for a scene's kind; its subsets are scene filters, e.g. the synthetic world's
    ``pedestrians_ahead.yaml``). A split folder laid out as NAVSIM v2's two-stage splits
    (``<src>/<split>/openscene_meta_datas``, ...) is read with its synthetic scenes."""

    name = "navsim"
    version = "1.2.0"
    extras = "navsim"

    def __init__(
        self,
        split: str | None = None,
        scene_filter: str | None = None,
        maps: str | None = None,
        num_history_frames: int | None = None,
        num_future_frames: int | None = None,
        frame_interval: int | None = None,
        map_radius: float = 100.0,
        two_stage_mapping: str | None = None,
        tag_filters: str | None = None,
    ) -> None:
        self.split = split
        self.filter = read_scene_filter(Path(scene_filter)) if scene_filter else None
        self.filter_path = scene_filter
        self.maps = Path(maps) if maps else None
        given = self.filter or SceneFilter("all")
        self.history = num_history_frames or given.num_history_frames or DEFAULT_HISTORY
        self.future = num_future_frames or given.num_future_frames or DEFAULT_FUTURE
        self.interval = frame_interval or given.frame_interval or 1
        self.has_route = given.has_route
        self.map_radius = map_radius
        if self.history < 2 or self.future < 1 or self.interval < 1:
            raise ValueError("need num_history_frames >= 2, num_future_frames >= 1 and frame_interval >= 1")
        self.mapping = read_two_stage_mapping(Path(two_stage_mapping)) if two_stage_mapping else None
        self._roles = two_stage_roles(self.mapping or [])
        self.tag_filters = tag_filters
        tagging = [read_scene_filter(Path(path)) for path in (tag_filters or "").split(",") if path]
        self._tags = {f"scene_filter:{f.name}": f.tokens or frozenset() for f in tagging}
        self._filter_problems: list[dict[str, Any]] = []

    def options(self) -> dict[str, Any]:
        return {
            "split": self.split,
            "scene_filter": self.filter_path,
            "maps": None if self.maps is None else str(self.maps),
            "num_history_frames": self.history,
            "num_future_frames": self.future,
            "frame_interval": self.interval,
            "map_radius": self.map_radius,
            "tag_filters": self.tag_filters,
        }

    def list_logs(self, src: Path) -> list[LogRef]:
        two_stage = Path(src) / (self.split or "") / TWO_STAGE_LOGS
        if self.split and two_stage.is_dir():
            return self._list_two_stage(Path(src), self.split)
        root = Path(src) / "navsim_logs"
        if not root.is_dir():
            raise FileNotFoundError(f"{root} does not exist: src must be an OpenScene root with navsim_logs/")
        splits = [self.split] if self.split else sorted(p.name for p in root.iterdir() if p.is_dir())
        refs = []
        for split in splits:
            if not (root / split).is_dir():
                raise FileNotFoundError(f"split folder {root / split} does not exist")
            refs += self._log_refs(root / split, Path(src) / "sensor_blobs" / split, split)
        self._filter_problems = self._check_filter(refs, []) + self._orphan_sensors(refs)
        return refs

    def _orphan_sensors(self, logs: list[LogRef]) -> list[dict[str, Any]]:
        """Sensor folders of logs with no log pickle: a log pickle deleted or lost in a download leaves its sensor
        blobs behind, and its scenes would otherwise vanish without a word."""
        problems = []
        for folder in sorted({Path(ref.extra["sensors"]) for ref in logs}):
            listed = {ref.log_id for ref in logs if Path(ref.extra["sensors"]) == folder}
            for log in sorted(p.name for p in folder.iterdir() if p.is_dir()) if folder.is_dir() else []:
                wanted = self.filter is None or self.filter.log_names is None or log in self.filter.log_names
                if wanted and log not in listed:
                    error = f"{folder / log}: sensor blobs of log {log!r}, which has no log pickle {log}.pkl"
                    problems.append({"log": log, "error": error})
        return problems

    def _log_refs(self, logs: Path, sensors: Path, split: str) -> list[LogRef]:
        refs = []
        for path in sorted(logs.glob("*.pkl")):
            if self.filter and self.filter.log_names is not None and path.stem not in self.filter.log_names:
                continue
            refs.append(LogRef(path.stem, split, str(path), {"sensors": str(sensors)}))
        return refs

    def _list_two_stage(self, src: Path, split: str) -> list[LogRef]:
        """A v2 two-stage split folder: its logs (stage 1), then one work item per synthetic scene (stage 2)."""
        folder = src / split
        refs = self._log_refs(folder / TWO_STAGE_LOGS, folder / TWO_STAGE_SENSORS, split)
        wanted = self.filter.synthetic_tokens if self.filter else None
        missing: list[str] = []
        if self.filter is None or self.filter.include_synthetic or self.mapping is not None:
            scenes = folder / TWO_STAGE_SYNTHETIC
            stems = {path.stem: path for path in sorted(scenes.glob("*.pkl"))}
            tokens = sorted(stems if wanted is None else wanted)
            missing = [token for token in tokens if token not in stems]
            extra = {"sensors": str(folder / TWO_STAGE_SENSORS), "logs": str(folder / TWO_STAGE_LOGS), SYNTHETIC: True}
            refs += [LogRef(token, split, str(stems[token]), extra) for token in tokens if token in stems]
        self._filter_problems = self._check_filter([ref for ref in refs if SYNTHETIC not in ref.extra], missing)
        return refs

    def tags(self, token: str) -> list[str]:
        """The tags of scene ``token``: one per ``tag_filters`` scene filter that lists it."""
        return [tag for tag, tokens in self._tags.items() if token in tokens]

    def two_stage_extras(self, token: str) -> dict[str, Any]:
        """``meta.extras.navsim`` fields of a token of the two-stage mapping: its stage (1 or 2), role and group."""
        return dict(self._roles.get(token, {}))

    def windows(self, frames: list[dict[str, Any]], where: str) -> Iterator[tuple[int, int]]:
        """(first, current) frame indices of NAVSIM's scenes in a log, before the token filter."""
        size = self.history + self.future
        for start in range(0, len(frames) - size + 1, self.interval):
            current = start + self.history - 1
            if self.has_route and not required(frames[current], "roadblock_ids", f"{where} frame {current}"):
                continue
            yield start, current

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        if SYNTHETIC in log.extra:
            yield SyntheticScene(self, log).sample()
            return
        path = Path(log.path)
        frames = load_log(path)
        scenes = LogScenes(self, log, frames)
        for start, current in self.windows(frames, str(path)):
            token = required(frames[current], "token", scenes.where(current), str)
            if self.filter is None or self.filter.tokens is None or token in self.filter.tokens:
                try:
                    yield scenes.sample(start, current)
                except UserError:
                    raise
                except (TypeError, ValueError, KeyError, IndexError, AttributeError) as err:
                    # a log value of the wrong type (a string where a number goes, a number where a list goes) fails
                    # in numpy or a lookup deep in the builder: named here by the log file and frame
                    problem = f"a value of an unexpected type ({type(err).__name__}: {err})"
                    raise NavsimFormatError(f"{scenes.where(current)}: {problem}") from err

    def bad_records(self) -> list[dict[str, Any]]:
        """What the scene filter selects and :meth:`list_logs` found nowhere: log names without a pickle, synthetic
        tokens without a scene pickle, tokens in no readable log with a full window."""
        return list(self._filter_problems)

    def _check_filter(self, logs: list[LogRef], missing_synthetic: list[str]) -> list[dict[str, Any]]:
        """The scene filter's entries that ``logs`` (listed logged scenes) and the synthetic folder do not provide.

        A filter with ``tokens`` costs one more read of each selected log here; a log that cannot be read is left to
        its own conversion to report."""
        if self.filter is None:
            return []
        where = f"scene filter {self.filter_path}"
        problems = []
        missing_logs = sorted((self.filter.log_names or set()) - {ref.log_id for ref in logs})
        if missing_logs:
            names = listing(missing_logs)
            problems.append(f"{where}: field 'log_names' has {len(missing_logs)} logs with no pickle: {names}")
        if missing_synthetic:
            names = listing(missing_synthetic)
            problems.append(f"{where}: {len(missing_synthetic)} synthetic scene tokens with no pickle: {names}")
        if self.filter.tokens is not None:
            scenes, unreadable = {}, []
            for ref in logs:
                try:
                    frames = load_log(Path(ref.path))
                    scenes[ref.log_id] = {str(frames[c].get("token")) for _, c in self.windows(frames, ref.path)}
                except (OSError, ValueError):
                    unreadable.append(ref.log_id)
            found = set().union(*scenes.values())
            missing = sorted(self.filter.tokens - found)
            if missing:
                problems.append(
                    f"{where}: field 'tokens' has {len(missing)} tokens in no readable log with a full "
                    f"{self.history}+{self.future}-frame window: {listing(missing)}"
                    + (f" (unreadable logs: {listing(unreadable)})" if unreadable else "")
                )
            problems += [f"{where}: {problem}" for problem in cut_short(scenes, self.filter)]
        return [{"scene_filter": str(self.filter_path), "error": problem} for problem in problems]

    def describe(self) -> dict[str, Any]:
        return {
            "dataset": "navsim",
            "rate_hz": 2.0,
            "num_history_frames": self.history,
            "num_future_frames": self.future,
            "horizon_s": self.future * 0.5,
            "cameras": list(CAMERAS.values()),
            "scene_filter": self.filter.name if self.filter else None,
            "maps": self.maps is not None,
            "bev": navsim_map.BEV_META if self.maps is not None else None,
            "two_stage": None
            if self.mapping is None
            else {
                "stage_one_tokens": [t for g in self.mapping for t in (g.original, g.previous)],
                "stage_two_tokens": [t for g in self.mapping for pair in g.pairs for t in pair],
                "reactive_all_mapping": [[g.original, g.previous, [list(p) for p in g.pairs]] for g in self.mapping],
            },
        }


def cut_short(scenes: dict[str, set[str]], scene_filter: SceneFilter) -> list[str]:
    """Signs of a scene filter cut short at a line, which parses and drops scenes without a word: logs its
    ``log_names`` names but none of whose scenes its ``tokens`` select (the logs after the cut), and the log of the
    list's last token when the list holds under half the share of its scenes that it holds of the other logs' (the
    log the cut fell in). ``scenes``: each readable log's scene tokens. A filter that lists few scenes of every log
    (navtrain) shows neither."""
    tokens = scene_filter.tokens or frozenset()
    problems = []
    unselected = [log for log in sorted(scene_filter.log_names or ()) if scenes.get(log) and not scenes[log] & tokens]
    if unselected:
        problems.append(
            f"field 'log_names' names {len(unselected)} logs none of whose scenes field 'tokens' selects (cut short?): "
            + listing(unselected)
        )
    last = next((log for log, windows in scenes.items() if scene_filter.last_token in windows), None)
    others = [len(w & tokens) / len(w) for log, w in scenes.items() if log != last and w & tokens]
    if last is not None and others:
        listed, total, typical = len(scenes[last] & tokens), len(scenes[last]), statistics.median(others)
        if listed / total < typical / 2:
            problems.append(
                f"field 'tokens' ends with {listed} of the {total} scenes of log {last}, and lists {typical:.0%} of "
                "a typical other log's (cut short?)"
            )
    return problems
