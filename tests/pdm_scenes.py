"""Hand-built PDM scenes for the v1.1 and v2.2 scoring tests: a straight road, boxes along it, ego state rows."""

import numpy as np

from lead_s2r.schema import BoxClass, MapKind
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex

# ---------------------------------------------------------------------------------------------------------------
# Hand-built scenes. A straight road along +x: forward roadblock 1 (lanes 11: y in [-1.75, 1.75], 12: [1.75, 5.25]),
# oncoming roadblock 2 (lane 21: [5.25, 8.75]). The route is lanes 11 and 12; the centreline is y = 0.
# ---------------------------------------------------------------------------------------------------------------

ROAD = [
    (1, MapKind.ROADBLOCK, -1.75, 5.25),
    (11, MapKind.LANE, -1.75, 1.75),
    (12, MapKind.LANE, 1.75, 5.25),
    (2, MapKind.ROADBLOCK, 5.25, 8.75),
    (21, MapKind.LANE, 5.25, 8.75),
]
KEYFRAMES = np.arange(11) * 0.5
TIMES = np.arange(41) * 0.1


def road_scene(agents: list[dict] | None = None, route: tuple[int, ...] = (11, 12)) -> PDMScene:
    """The straight road with agents given as ``{"class", "size", "poses" (11, 3), "velocity" (11, 2), "valid"}``."""
    rings = [np.array([[-100.0, y0], [200.0, y0], [200.0, y1], [-100.0, y1]]) for _, _, y0, y1 in ROAD]
    agents = agents or []
    return PDMScene(
        polygon_xy=np.concatenate(rings),
        polygon_offsets=np.arange(len(rings) + 1) * 4,
        polygon_id=np.array([p[0] for p in ROAD]),
        polygon_kind=np.array([p[1] for p in ROAD]),
        route_lane_ids=np.array(route),
        centerline=np.stack([np.linspace(-100, 200, 301), np.zeros(301), np.zeros(301)], -1),
        agent_t=KEYFRAMES,
        agent_poses=np.array([a["poses"] for a in agents]).reshape(-1, 11, 3),
        agent_velocity=np.array([a["velocity"] for a in agents]).reshape(-1, 11, 2),
        agent_valid=np.array([a.get("valid", np.ones(11, bool)) for a in agents]).reshape(-1, 11),
        agent_size=np.array([a["size"] for a in agents]).reshape(-1, 3),
        agent_class=np.array([a["class"] for a in agents], np.int64),
        ego_velocity=np.zeros(2),
        ego_acceleration=np.zeros(2),
        key="hand-built",
    )


def agent(box_class: BoxClass, x: float, y: float, vx: float = 0.0, size: tuple = (4.8, 2.0, 1.6)) -> dict:
    """A box moving along x at ``vx`` from ``(x, y)``, seen at all 11 keyframes."""
    poses = np.stack([x + vx * KEYFRAMES, np.full(11, y), np.zeros(11)], -1)
    return {"class": box_class, "size": size, "poses": poses, "velocity": np.stack([np.full(11, vx), np.zeros(11)], -1)}


def drive(x: np.ndarray, y: np.ndarray | float = 0.0, speed: np.ndarray | None = None) -> np.ndarray:
    """One row of rear-axle states ``(1, 41, 11)`` along ``x (41,)``/``y``; heading from the path, speed and
    acceleration by finite differences unless given."""
    y = np.broadcast_to(np.asarray(y, np.float64), x.shape)
    states = np.zeros((1, len(x), STATE_SIZE))
    states[0, :, StateIndex.X], states[0, :, StateIndex.Y] = x, y
    dx, dy = np.gradient(x, 0.1), np.gradient(y, 0.1)
    states[0, :, StateIndex.HEADING] = np.arctan2(dy, dx) if np.hypot(dx, dy).max() > 0 else 0.0
    states[0, :, StateIndex.VELOCITY_X] = np.hypot(dx, dy) if speed is None else speed
    states[0, :, StateIndex.ACCELERATION_X] = np.gradient(states[0, :, StateIndex.VELOCITY_X], 0.1)
    return states
