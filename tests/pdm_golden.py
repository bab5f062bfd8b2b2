"""The official NAVSIM golden cases (v1.1 ``navsim_pdms_v11_official.json.gz``, v2.2
``navsim_epdms_v22_official.json.gz`` in ``tests/data``) as ego-frame PDM scenes.

The files store everything in a global (UTM-like) frame; a scene is moved into the ego frame at ``ego_initial``
(rear axle at the origin, x along the initial heading), as a converted NAVSIM sample would be. v2.2 cases add the
traffic lights, the logged past and future, previous frames for EC, and ego dynamics that NAVSIM reads as float32.
"""

import gzip
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.schema import MapKind
from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.scene import PDMScene, PreviousFrame
from lead_s2r_adapters.navsim_io import BOX_CLASSES

#: The official records' short sub-score names -> our (NAVSIM's) column names.
SHORT = {
    "NC": epdms.NC,
    "DAC": epdms.DAC,
    "DDC": epdms.DDC,
    "TLC": epdms.TLC,
    "EP": epdms.EP,
    "TTC": epdms.TTC,
    "LK": epdms.LK,
    "HC": epdms.HC,
}

GOLDEN = Path(__file__).parent / "data" / "navsim_pdms_v11_official.json.gz"
GOLDEN_V22 = Path(__file__).parent / "data" / "navsim_epdms_v22_official.json.gz"


def load_golden(path: Path = GOLDEN) -> dict[str, Any]:
    with gzip.open(path, "rt") as f:
        return json.load(f)


@dataclass
class EgoFrame:
    """The rigid transform from the golden file's global frame to the ego frame at ``ego_initial``."""

    x: float
    y: float
    heading: float

    def points(self, xy: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.heading), np.sin(self.heading)
        dx, dy = xy[..., 0] - self.x, xy[..., 1] - self.y
        return np.stack([c * dx + s * dy, -s * dx + c * dy], -1)

    def vectors(self, v: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.heading), np.sin(self.heading)
        return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], -1)

    def headings(self, h: np.ndarray) -> np.ndarray:
        h = np.asarray(h) - self.heading
        return np.arctan2(np.sin(h), np.cos(h))

    def poses(self, poses: np.ndarray) -> np.ndarray:
        poses = np.asarray(poses, np.float64)
        return np.concatenate([self.points(poses[..., :2]), self.headings(poses[..., 2])[..., None]], -1)

    def states(self, states: np.ndarray) -> np.ndarray:
        """Simulated states ``(..., 11)``: pose to the ego frame, body-frame dynamics unchanged."""
        out = np.array(states, np.float64)
        out[..., :3] = self.poses(out[..., :3])
        return out


def ego_frame(case: dict[str, Any]) -> EgoFrame:
    ego = case["ego_initial"]
    return EgoFrame(ego["x"], ego["y"], ego["heading"])


def _map_fields(case: dict[str, Any], frame: EgoFrame) -> dict[str, np.ndarray]:
    polygons = case["map"]["polygons"]
    rings = [frame.points(np.asarray(p["exterior"], np.float64)) for p in polygons]
    return {
        "polygon_xy": np.concatenate(rings),
        "polygon_offsets": np.concatenate([[0], np.cumsum([len(r) for r in rings])]).astype(np.int64),
        "polygon_id": np.array([int(p["id"]) for p in polygons], np.int64),
        "polygon_kind": np.array([MapKind[p["layer"]] for p in polygons], np.int64),
        "route_lane_ids": np.array([int(i) for i in case["map"]["route_lane_ids"]], np.int64),
        "centerline": frame.poses(np.asarray(case["map"]["centerline"], np.float64)),
    }


def _agent_fields(case: dict[str, Any], frame: EgoFrame) -> dict[str, np.ndarray]:
    agents, num_keyframes = case["agents"], len(case["keyframe_times_s"])
    poses = np.full((len(agents), num_keyframes, 3), np.nan)
    velocity = np.full((len(agents), num_keyframes, 2), np.nan)
    for m, agent in enumerate(agents):
        for k, key in enumerate(agent["keyframes_2hz"]):
            if key is not None:
                poses[m, k] = frame.poses(np.array([key["x"], key["y"], key["heading"]]))
                velocity[m, k] = frame.vectors(np.array([key["vx"], key["vy"]]))
    return {
        "agent_t": np.asarray(case["keyframe_times_s"], np.float64),
        "agent_poses": poses,
        "agent_velocity": velocity,
        "agent_valid": np.isfinite(poses[..., 0]),
        "agent_size": np.array([[a["length"], a["width"], a["height"]] for a in agents], np.float64).reshape(-1, 3),
        "agent_class": np.array([BOX_CLASSES[a["type"]] for a in agents], np.int64),
    }


def _dynamics(state: dict[str, Any], float32: bool) -> dict[str, np.ndarray]:
    dtype = np.float32 if float32 else np.float64
    return {
        "ego_velocity": np.array([state["vx"], state["vy"]], dtype).astype(np.float64),
        "ego_acceleration": np.array([state["ax"], state["ay"]], dtype).astype(np.float64),
    }


def _red_light_fields(case: dict[str, Any]) -> dict[str, np.ndarray]:
    """v2.2 ``traffic_lights`` (per keyframe ``[{lane_connector_id, is_red}]``) as ``scoring.npz``'s red lights."""
    red = [
        [int(light["lane_connector_id"]) for light in lights if light["is_red"]] for lights in case["traffic_lights"]
    ]
    return {
        "red_light_t": np.asarray(case["keyframe_times_s"], np.float64)[: len(red)],
        "red_light_ids": np.array([i for ids in red for i in ids], np.int64),
        "red_light_offsets": np.concatenate([[0], np.cumsum([len(ids) for ids in red])]).astype(np.int64),
    }


def _v2_fields(case: dict[str, Any], frame: EgoFrame) -> dict[str, Any]:
    past = case["ego_past"]
    rows = [
        [p["t_s"], *frame.poses(np.array([p["x"], p["y"], p["heading"]])), p["vx"], p["vy"], p["ax"], p["ay"]]
        for p in past
    ]
    ego_past = np.array(rows, np.float64)
    ego_past[:, 4:] = ego_past[:, 4:].astype(np.float32)
    human = case.get("human_trajectory")
    return {
        **_red_light_fields(case),
        "light_route_lane_ids": np.array([int(i) for i in case["map"]["traffic_light_route_lane_ids"]], np.int64),
        "ego_past": ego_past,
        "human_poses": None if not human else np.asarray(human["poses"], np.float64),
        "human_interval": 0.5 if not human else float(human["interval_s"]),
        "is_synthetic": case["scene_type"] == "SYNTHETIC",
    }


def golden_scene(case: dict[str, Any]) -> PDMScene:
    """One golden case as an ego-frame :class:`PDMScene` (v2.2 cases with their v2 fields and float32 dynamics)."""
    frame, ego = ego_frame(case), case["ego_initial"]
    v2 = "ego_past" in case
    return PDMScene(
        **_map_fields(case, frame),
        **_agent_fields(case, frame),
        **_dynamics(ego, float32=v2),
        tire_steering_angle=float(ego["tire_steering_angle"]),
        key=case["id"],
        t0_us=int(case["t0_us"]),
        **(_v2_fields(case, frame) if v2 else {}),
    )


def previous_frame(case: dict[str, Any], trajectory: dict[str, Any]) -> PreviousFrame | None:
    """A v2.2 trajectory's ``previous_frame`` (ego 0.5 s earlier, its plan) in the current ego frame, or None."""
    previous = trajectory.get("previous_frame")
    if not previous:
        return None
    state = previous["ego_state"]
    dynamics = _dynamics(state, float32=True)
    return PreviousFrame(
        ego_pose=ego_frame(case).poses(np.array([state["x"], state["y"], state["heading"]])),
        ego_velocity=dynamics["ego_velocity"],
        ego_acceleration=dynamics["ego_acceleration"],
        poses=np.asarray(previous["poses"], np.float64),
        interval=float(previous["interval_s"]),
        frame_gap=-float(state["t_s"]),
    )


def agent_states_10hz(case: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The official 10 Hz agent states ``(M, 51, 5)`` (x, y, heading, vx, vy) in the ego frame and their mask."""
    frame = ego_frame(case)
    rows = [[s if s is not None else [np.nan] * 5 for s in a["states_10hz"]] for a in case["agents"]]
    states = np.asarray(rows, np.float64).reshape(len(rows), -1, 5)
    states[..., :3] = frame.poses(states[..., :3])
    states[..., 3:] = frame.vectors(states[..., 3:])
    return states, np.isfinite(states[..., 0])


def simulated_states(case: dict[str, Any]) -> np.ndarray:
    """``(1 + J, 41, 11)`` official simulated states in the ego frame: the reference, then each trajectory."""
    frame = ego_frame(case)
    rows = [case["reference_trajectory"]["official"]["simulated_states"]]
    rows += [t["official"]["simulated_states"] for t in case["trajectories"]]
    return frame.states(np.asarray(rows, np.float64))


def reference_poses(case: dict[str, Any]) -> np.ndarray:
    """The reference trajectory ``(51, 3)`` at 0.1 s from t = 0, in the ego frame."""
    return ego_frame(case).poses(np.asarray(case["reference_trajectory"]["poses"], np.float64))
