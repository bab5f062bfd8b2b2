"""A converted NAVSIM sample as a :class:`PDMScene`: the only place that knows the sample layout of ``scoring``,
``boxes``, ``agents_future`` and ``meta`` (docs/datasets/navsim.md).

Agent tracks are the current boxes (t = 0) followed by ``agents_future``'s keyframes; its rows ``0..num_boxes-1``
are the current boxes, so a track keeps one row over time. The route is corrected and its centreline built here,
once per sample, because both depend on the map only (:mod:`lead_s2r.scoring.pdm.route`).
"""

from typing import Any

import numpy as np

from lead_s2r.schema import SchemaError
from lead_s2r.scoring.pdm.route import LaneGraph, RouteError, plan_route
from lead_s2r.scoring.pdm.scene import PDMScene

NEEDS_MAPS = "re-convert the NAVSIM data with maps (`lead-s2r convert navsim ... --maps <nuPlan maps root>`)"


def agent_tracks(sample: dict[str, Any]) -> dict[str, np.ndarray]:
    """``agent_t``, ``agent_poses``, ``agent_velocity``, ``agent_valid``, ``agent_size``, ``agent_class`` of a
    sample: t = 0 from ``boxes``, later keyframes from ``agents_future`` (either may be absent).

    A velocity the source does not know (NaN; docs/schema.md) is 0 here: PDM-Closed forecasts that box standing where
    it was seen and the collision rules count it as stopped (NAVSIM's devkit has no unknown velocity to follow)."""
    boxes = np.asarray(sample.get("boxes", np.zeros((0, 10))), np.float64).reshape(-1, 10)
    future = sample.get("agents_future")
    count = len(boxes)
    if future is None:
        t_future = np.zeros(0)
        poses_future = np.zeros((count, 0, 3))
        velocity_future = np.zeros((count, 0, 2))
        valid_future = np.zeros((count, 0), bool)
        size, classes = boxes[:, 3:6], boxes[:, 9].astype(np.int64)
    else:
        t_future = np.asarray(future["t"], np.float64)
        poses_future = np.asarray(future["poses"], np.float64)
        velocity_future = np.asarray(future["velocity"], np.float64)
        valid_future = np.asarray(future["valid"], bool)
        size = np.asarray(future["size"], np.float64).reshape(-1, 3)
        classes = np.asarray(future["class"], np.int64)
        if int(future["num_boxes"]) != count or len(poses_future) < count:
            raise SchemaError(
                sample.get("__key__", "?"),
                "agents_future",
                f"num_boxes {int(future['num_boxes'])} disagrees with the {count} boxes; re-convert the sample",
            )
    total = len(poses_future)
    now_poses = np.zeros((total, 1, 3))
    now_velocity = np.zeros((total, 1, 2))
    now_valid = np.zeros((total, 1), bool)
    now_poses[:count, 0] = boxes[:, [0, 1, 6]]
    now_velocity[:count, 0] = boxes[:, 7:9]
    now_valid[:count] = True
    size = size.copy()
    size[:count] = boxes[:, 3:6]
    return {
        "agent_t": np.concatenate([[0.0], t_future]),
        "agent_poses": np.nan_to_num(np.concatenate([now_poses, poses_future], axis=1)),
        "agent_velocity": np.nan_to_num(np.concatenate([now_velocity, velocity_future], axis=1)),
        "agent_valid": np.concatenate([now_valid, valid_future], axis=1),
        "agent_size": size,
        "agent_class": classes,
    }


def scene_from_sample(sample: dict[str, Any]) -> PDMScene:
    """The scoring scene of a converted NAVSIM sample, with PDM-Closed's corrected route and centreline; a
    :class:`RouteError` names the key when the route cannot be followed in the map context."""
    key = sample.get("__key__", "")
    scoring = sample.get("scoring")
    if scoring is None:
        raise SchemaError(
            sample.get("__key__", "?"), "scoring", f"missing: the PDM score needs the map context; {NEEDS_MAPS}"
        )
    meta = sample["meta"]
    graph = LaneGraph.from_scoring(scoring)
    try:
        route = plan_route(graph, np.asarray(scoring["route_roadblock_ids"], np.int64).tolist())
    except RouteError as err:
        raise RouteError(f"sample {key!r}, field 'scoring': {err}; PDM-Closed needs an on-route lane") from None
    uncorrected = set(np.asarray(scoring["route_roadblock_ids"], np.int64).tolist())
    future = sample.get("future")
    ego = meta["ego"]
    return PDMScene(
        polygon_xy=np.asarray(scoring["polygon_xy"], np.float64),
        polygon_offsets=np.asarray(scoring["polygon_offsets"], np.int64),
        polygon_id=np.asarray(scoring["polygon_id"], np.int64),
        polygon_kind=np.asarray(scoring["polygon_kind"], np.int64),
        route_lane_ids=np.asarray(route.lane_ids, np.int64),
        centerline=route.centerline,
        **agent_tracks(sample),
        ego_velocity=np.asarray(ego["velocity"], np.float64),
        ego_acceleration=np.asarray(ego["acceleration"], np.float64),
        key=key,
        t0_us=int(meta["timestamp_us"]) if "timestamp_us" in meta else None,
        red_light_t=np.asarray(scoring["red_light_t"], np.float64),
        red_light_ids=np.asarray(scoring["red_light_ids"], np.int64),
        red_light_offsets=np.asarray(scoring["red_light_offsets"], np.int64),
        light_route_lane_ids=np.asarray(
            [lane for lane, block in graph.lane_block.items() if block in uncorrected], np.int64
        ),
        ego_past=np.asarray(scoring["ego_past"], np.float64) if "ego_past" in scoring else None,
        human_poses=None if future is None else np.asarray(future[:, 1:4], np.float64),
        human_interval=0.5,
        is_synthetic=bool(meta.get("is_synthetic", False)),
        speed_limit_mps=route.speed_limit,
    )
