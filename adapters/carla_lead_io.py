"""Readers for the files of a LEAD route folder; every failure names the file (and the field where there is one).

LEAD's ``.pkl`` files are LZMA streams holding pickles. Pickles can run arbitrary code, so they are loaded with an
unpickler that only admits plain builtin containers/scalars and numpy arrays/scalars.
"""

import importlib.util
import json
import lzma
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.errors import UserError
from lead_s2r.formats import restricted_pickle
from lead_s2r_adapters.laz_decoder import LazDecodeError, decode


class LeadFormatError(UserError, ValueError):
    """A LEAD file that cannot be read as LEAD writes it; the message names the file and the field."""

    def __init__(self, path: Path, problem: str, field: str | None = None) -> None:
        where = f"{path}" if field is None else f"{path} (field {field!r})"
        super().__init__(f"{where}: {problem}")


def read_pickle(path: Path) -> Any:
    """Load one LZMA-compressed LEAD pickle with the restricted unpickler."""
    try:
        with lzma.open(path, "rb") as file:
            return restricted_pickle.load(file)
    except (lzma.LZMAError, EOFError) as err:
        raise LeadFormatError(path, f"truncated or corrupt LZMA pickle ({err or type(err).__name__})") from err
    except restricted_pickle.DAMAGED as err:
        raise LeadFormatError(path, f"not a valid pickle ({type(err).__name__}: {err})") from err
    except OSError as err:
        raise LeadFormatError(path, f"cannot be read ({err})") from err


def field(record: dict[str, Any], name: str, path: Path) -> Any:
    """``record[name]`` or an error naming the file and the missing field."""
    if not isinstance(record, dict):
        raise LeadFormatError(path, f"expected a dict, got {type(record).__name__}")
    if name not in record:
        raise LeadFormatError(path, "required field is missing", name)
    return record[name]


def array(record: dict[str, Any], name: str, path: Path, columns: int | None = None) -> np.ndarray:
    """A numeric field as float64 (N,) or (N, columns), with an error naming file and field on a bad shape."""
    value = field(record, name, path)  # a missing field says so, not "not numeric"
    try:
        values = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise LeadFormatError(path, f"not numeric ({err})", name) from err
    if columns is not None:
        if values.size == 0:
            values = values.reshape(0, columns)
        if values.ndim != 2 or values.shape[1] < columns:
            raise LeadFormatError(path, f"expected shape (N, >={columns}), got {values.shape}", name)
    return values


def track_poses(record: dict[str, Any], kind: str, path: Path, where: str = "") -> np.ndarray:
    """(N, 3) x, y, yaw of LEAD's ``<kind>_positions`` and ``<kind>_yaws`` (past / future), which must agree in length;
    ``where`` says whose they are in an error (a box's)."""
    positions, yaws = array(record, f"{kind}_positions", path, columns=2), array(record, f"{kind}_yaws", path)
    if len(yaws) != len(positions):
        raise LeadFormatError(path, f"{where}{len(yaws)} yaws for {len(positions)} {kind} positions", f"{kind}_yaws")
    return np.column_stack([positions[:, :2], yaws])


def read_laz(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """LiDAR points (N, 3) in metres and the per-point ``time`` sweep index (N,) of one LEAD ``.laz`` file, decoded in
    a helper process (:mod:`lead_s2r_adapters.laz_decoder`): a damaged file can abort the decoder."""
    if importlib.util.find_spec("laspy") is None or importlib.util.find_spec("lazrs") is None:  # pragma: no cover
        raise ImportError("reading LEAD LiDAR needs laspy with lazrs: pip install 'lead-s2r[carla]'")
    try:
        points = decode(path)
    except LazDecodeError as err:
        raise LeadFormatError(path, f"corrupt LAZ file ({err})") from None
    return points[:, :3], points[:, 3]


def is_route(folder: Path) -> bool:
    """Whether ``folder`` is a LEAD route folder (finished or not)."""
    return (folder / "bboxes").is_dir() or (folder / "metas").is_dir() or (folder / "results.json").is_file()


def route_frames(folder: Path) -> list[str]:
    """Frame names (``0000``...) of a route: LEAD counts frames by the files in ``bboxes/``; every frame has a
    ``metas/`` pickle too, and frames are numbered without gaps, so a deleted file of either is an error naming it,
    not a frame silently left out."""
    names = {path.stem for sub in ("bboxes", "metas") for path in (folder / sub).glob("*.pkl")}
    if not names:
        raise LeadFormatError(folder / "bboxes", "no frames (LEAD counts frames by the files in bboxes/)")
    if not all(name.isdigit() for name in names):
        odd = sorted(name for name in names if not name.isdigit())[0]
        raise LeadFormatError(folder / "bboxes", f"frame file {odd!r}.pkl is not named by a frame number")
    width = len(min(names))
    numbers = sorted(int(name) for name in names)
    expected = [f"{number:0{width}d}" for number in range(numbers[0], numbers[-1] + 1)]
    for name in expected:
        for sub in ("bboxes", "metas"):
            if not (folder / sub / f"{name}.pkl").is_file():
                raise LeadFormatError(folder / sub / f"{name}.pkl", "missing: the route's other frames have it")
    return expected


def frame_file(folder: Path, sensor: str, name: str, suffix: str) -> Path | None:
    """The file of frame ``name`` in the sensor folder ``sensor``, None where the route has no such folder (a rig
    or sensor it did not record); missing from a folder that holds other frames is an error naming it."""
    path = folder / sensor / f"{name}{suffix}"
    if path.is_file():
        return path
    if (folder / sensor).is_dir():
        raise LeadFormatError(path, f"missing: the route's {sensor}/ folder holds other frames")
    return None


RADAR_KEYS = ("radar1", "radar2", "radar3", "radar4")


def read_radar(path: Path) -> list[np.ndarray]:
    """The four radar clouds (n, 4) = x, y, z, radial velocity of one LEAD radar ``.npz`` (float16 on disk)."""
    try:
        npz = np.load(path, allow_pickle=False)
        if isinstance(npz, np.lib.npyio.NpzFile):  # a damaged zip magic reads as an .npy
            with npz:
                clouds = [npz[key] if key in npz.files else np.zeros((0, 4), np.float16) for key in RADAR_KEYS]
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, zlib.error) as err:  # np.load of a zip
        raise LeadFormatError(path, f"corrupt radar npz ({type(err).__name__}: {err})") from err
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise LeadFormatError(path, "not an npz archive")
    for key, cloud in zip(RADAR_KEYS, clouds, strict=True):
        if cloud.ndim != 2 or cloud.shape[1] != 4:
            raise LeadFormatError(path, f"expected shape (n, 4), got {cloud.shape}", key)
    return [cloud.astype(np.float64) for cloud in clouds]


def read_png(path: Path) -> np.ndarray:
    """A single-channel uint8 PNG label exactly as stored."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise LeadFormatError(path, "cannot be decoded as PNG")
    if image.ndim != 2 or image.dtype != np.uint8:
        raise LeadFormatError(path, f"expected a single-channel uint8 image, got {image.dtype} {image.shape}")
    return image


def read_jpeg(path: Path) -> bytes:
    """JPEG bytes as stored (never decoded and re-encoded)."""
    data = path.read_bytes()
    if data[:2] != b"\xff\xd8":
        raise LeadFormatError(path, "not a JPEG file (no FFD8 start marker)")
    return data


#: Infractions LEAD tolerates in a route it would otherwise drop (``route_filtering.py``).
_MIN_SPEED = "min_speed_infractions"
_OUTSIDE_LANES = "outside_route_lanes"


def route_skip_reason(folder: Path, keep_failed: bool = False) -> str | None:
    """Why LEAD's route filter leaves this route out, or None if it keeps it. An unfinished route (no results.json or
    no first meta) is always left out; a finished one is kept with ``keep_failed``, else only if: score 100; or only
    min-speed infractions; or status Completed with only min-speed / outside-lane ones."""
    results = folder / "results.json"
    if not results.is_file():
        return "no results.json (the route did not finish recording)"
    if not (folder / "metas" / "0000.pkl").is_file():
        return "no metas/0000.pkl"
    try:
        record = json.loads(results.read_text())
    except json.JSONDecodeError as err:
        raise LeadFormatError(results, f"invalid JSON ({err})") from err
    if keep_failed:
        return None
    score = float(field(field(record, "scores", results), "score_composed", results))
    if score >= 100.0:
        return None
    kinds = {name for name, items in (record.get("infractions") or {}).items() if items}
    if kinds <= {_MIN_SPEED}:
        return None
    status = str(record.get("status", ""))
    if status.startswith("Completed") and kinds <= {_MIN_SPEED, _OUTSIDE_LANES}:
        return None
    return f"failed route: status {status!r}, score {score:g}, infractions {sorted(kinds)}"
