"""A tiny in-tree adapter for driver tests: each ``<log>.json`` under src lists frames of a circular drive."""

import json
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lead_s2r.registry import Adapter, LogRef, SkipLog
from lead_s2r.schema import SCHEMA_VERSION, Command


def write_toy_logs(
    src: Path,
    n_logs: int,
    frames: int | Sequence[int],
    broken: tuple[int, ...] = (),
    skipped: tuple[int, ...] = (),
):
    """Write toy logs of ``frames`` frames each (or ``frames[i]`` for log i); ``broken`` logs fail half-way through,
    ``skipped`` logs ask to be left out."""
    src.mkdir(parents=True, exist_ok=True)
    for i in range(n_logs):
        length = frames if isinstance(frames, int) else frames[i]
        spec = {"frames": length, "yaw_rate": 0.1 * (i % 3 - 1), "fail_at": length // 2 if i in broken else None}
        spec["skip"] = i in skipped
        (src / f"log{i:03d}.json").write_text(json.dumps(spec))


def toy_sample(log_id: str, frame: int, yaw_rate: float = 0.1, rng: np.random.Generator | None = None) -> dict:
    """One valid schema v1 sample with every common field type."""
    rng = rng or np.random.default_rng(frame)
    t = np.arange(1, 9, dtype=np.float32) * 0.5
    future = np.stack([t, 5 * t, 0.5 * yaw_rate * t**2, yaw_rate * t], axis=1).astype(np.float32)
    tp = np.arange(-4, 0, dtype=np.float32) * 0.5
    past = np.stack([tp, 5 * tp, np.zeros_like(tp), np.zeros_like(tp)], axis=1).astype(np.float32)
    past = np.vstack([past, np.zeros((1, 4), np.float32)])
    image = rng.integers(0, 255, (32, 64, 3), dtype=np.uint8)
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 80])[1].tobytes()
    lidar = rng.normal(size=(50, 4)).astype(np.float32)
    boxes = np.zeros((2, 10), np.float32)
    boxes[:, :7] = rng.normal(size=(2, 7))
    boxes[:, 3:6] = np.abs(boxes[:, 3:6]) + 0.5  # sizes of real boxes (LEAD's CenterNet radius needs them)
    boxes[:, 9] = [0, 1]
    target_points = np.array([[-5, 0], [10, 2 * yaw_rate], [30, 8 * yaw_rate]], np.float32)
    camera = {
        "id": "front",
        "native_name": "CAM_F0",
        "width": 64,
        "height": 32,
        "K": [[40.0, 0, 32], [0, 40.0, 16], [0, 0, 1]],
        "distortion": [0.0] * 5,
        "cam_to_ego": np.eye(4).tolist(),
    }
    meta = {
        "schema_version": SCHEMA_VERSION,
        "dataset": "toy",
        "split": "train",
        "log_id": log_id,
        "frame_idx": frame,
        "timestamp_us": 1_000_000 + frame * 500_000,
        "is_synthetic": True,
        "location": None,
        "adapter": "toy",
        "adapter_version": "1",
        "ego": {
            "speed": 5.0,
            "velocity": [5.0, 0.0],
            "acceleration": [0.0, 0.0],
            "yaw_rate": yaw_rate,
            "command": int(Command.LEFT if yaw_rate > 0 else Command.STRAIGHT),
            "command_raw": 1,
        },
        "vehicle": {"length": 4.5, "width": 2.0, "wheel_base": 2.9, "rear_axle_to_center": 1.4},
        "cameras": [camera],
        "lidar_columns": ["x", "y", "z", "intensity"],
        "has": {"future": True, "lidar": True, "boxes": True, "target_points": True, "cam_front": True, "radar": False},
        "extras": {"toy": {"seed": frame}},
    }
    return {
        "__key__": f"toy_{log_id}_{frame:06d}",
        "meta": meta,
        "past": past,
        "future": future,
        "cam_front": jpeg,
        "lidar": lidar,
        "boxes": boxes,
        "target_points": target_points,
    }


class ToyAdapter(Adapter):
    name = "toy"
    version = "1"

    def __init__(self, sleep: float = 0.0) -> None:
        self.sleep = sleep

    def list_logs(self, src: Path) -> list[LogRef]:
        return [LogRef(path.stem, "train", str(path)) for path in sorted(Path(src).glob("*.json"))]

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        spec = json.loads(Path(log.path).read_text())
        if spec["skip"]:
            raise SkipLog("route failed")
        for frame in range(spec["frames"]):
            if frame == spec["fail_at"]:
                raise ValueError(f"{log.path}: frame {frame}: field 'pose' is corrupt")
            time.sleep(self.sleep)
            yield toy_sample(log.log_id, frame, spec["yaw_rate"])

    def options(self) -> dict[str, Any]:
        return {}  # sleep only slows the conversion down

    def describe(self) -> dict[str, Any]:
        return {"rates_hz": {"future": 2.0}}


class InterruptedToy(ToyAdapter):
    """Ctrl-C while converting log000, in whichever process converts it. Here, not in a test module: a worker
    unpickling it imports this light module, not a test module's imports (torch)."""

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        if log.log_id == "log000":
            raise KeyboardInterrupt
        yield from super().iter_samples(log)


def corrupt_header(tar: Path, member: str) -> None:
    """Break the checksum of ``member``'s tar header (bit rot mid-file): tarfile ends the stream there, silently."""
    data = bytearray(tar.read_bytes())
    header = data.index(member.encode())
    assert header % 512 == 0, "a name that needs a pax header: corrupt that one"
    data[header + 148 : header + 156] = b"0000000\0"  # the checksum field
    tar.write_bytes(bytes(data))
