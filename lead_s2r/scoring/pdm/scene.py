"""The scoring scene: what one NAVSIM sample holds for the PDM score, in the ego frame at t0 (rear axle), float64.

Field names and layouts mirror ``scoring.npz`` (map polygons as ragged arrays, red lights per 2 Hz keyframe), so a
converted sample maps onto a scene without renaming. v2-only fields are optional and empty when a source lacks them.
"""

from dataclasses import dataclass, field

import numpy as np
import shapely

from lead_s2r.scoring.pdm.vehicle import PACIFICA, VehicleParameters


def ragged_polygons(xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Shapely polygons from exterior rings laid end to end (``polygon_xy`` / ``polygon_offsets``)."""
    counts = np.diff(np.asarray(offsets, np.int64))
    rings = shapely.linearrings(np.asarray(xy, np.float64), indices=np.repeat(np.arange(len(counts)), counts))
    return shapely.polygons(rings)


@dataclass
class PDMScene:
    """One scene to score. M agents over T keyframes (2 Hz, t = 0 included); K map polygons."""

    # map: K polygon exteriors laid end to end (ring not closed), their nuPlan ids and MapKind codes
    polygon_xy: np.ndarray  # (P, 2)
    polygon_offsets: np.ndarray  # (K + 1,) int64
    polygon_id: np.ndarray  # (K,) int64
    polygon_kind: np.ndarray  # (K,) MapKind codes
    # route: on-route LANE / LANE_CONNECTOR ids (after PDM-Closed's route correction); the centreline of progress
    route_lane_ids: np.ndarray  # (R,) int64
    centerline: np.ndarray  # (L, 3) x, y, heading
    # agents at the keyframes: box centre pose, velocity (scene frame), which keyframes see the track
    agent_t: np.ndarray  # (T,) seconds, agent_t[0] == 0
    agent_poses: np.ndarray  # (M, T, 3) x, y, yaw
    agent_velocity: np.ndarray  # (M, T, 2) vx, vy
    agent_valid: np.ndarray  # (M, T) bool
    agent_size: np.ndarray  # (M, 3) length, width, height (first sighting)
    agent_class: np.ndarray  # (M,) BoxClass codes
    # ego at t0: rear-axle velocity and acceleration in the ego body frame
    ego_velocity: np.ndarray  # (2,)
    ego_acceleration: np.ndarray  # (2,)
    tire_steering_angle: float = 0.0
    vehicle: VehicleParameters = PACIFICA
    key: str = ""
    #: absolute time of t0 in microseconds: nuPlan truncates sample times to whole microseconds, so the exact
    #: interpolation (and the simulation after it) depends on it; None interpolates at exact multiples of 0.1 s
    t0_us: int | None = None
    # red lights per 2 Hz keyframe: lane-connector ids red at red_light_t[i] are red_light_ids[offsets[i]:offsets[i+1]]
    red_light_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    red_light_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    red_light_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    # v2 (EPDMS): lanes of the uncorrected route (only their red lights count), the logged past, the logged future
    light_route_lane_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    ego_past: np.ndarray | None = None  # (P, 8) t, x, y, heading, vx, vy, ax, ay (body frame)
    human_poses: np.ndarray | None = None  # (K, 3) at human_interval * (k + 1)
    human_interval: float = 0.5
    is_synthetic: bool = False
    # PDM-Closed: speed limit of its start lane (NaN: none in the map, IDM falls back to 15 m/s)
    speed_limit_mps: float = float("nan")


@dataclass
class PreviousFrame:
    """What EC needs of the frame ``frame_gap`` seconds before a scene (NAVSIM v2 pairs frames 0.5 s apart): the ego
    there (rear-axle pose in the *current* ego frame, body-frame velocity and acceleration) and the plan made there,
    ``poses (K, 3)`` in the *previous* ego frame at ``interval * (k + 1)``."""

    ego_pose: np.ndarray  # (3,)
    ego_velocity: np.ndarray  # (2,)
    ego_acceleration: np.ndarray  # (2,)
    poses: np.ndarray  # (K, 3)
    interval: float
    frame_gap: float = 0.5
