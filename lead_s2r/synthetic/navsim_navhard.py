"""A small ``navhard_two_stage`` split in NAVSIM v2's on-disk layout, with synthetic scene pickles holding nuPlan
objects, for end-to-end tests of the two-stage reading and scoring.

Writes, under ``out``::

    navhard_two_stage/openscene_meta_datas/<log>.pkl       stage-1 logs (OpenScene frame dicts, as navsim_logs)
    navhard_two_stage/sensor_blobs/<log>/...               their sensors, and the synthetic scenes' cameras
    navhard_two_stage/synthetic_scene_pickles/<17hex>.pkl  one synthetic (stage-2) scene each
    maps/us-nv-las-vegas-strip/9.15.1915/map.gpkg          the road network of :mod:`navsim_map`
    scene_filters/navhard_two_stage.yaml                   SceneFilter: stage-1 tokens, synthetic tokens
    train_test_split/navhard_two_stage.yaml                data_split + reactive_all_mapping

Each log (the logs of :mod:`navsim`, 20 frames at 2 Hz) gives one group. The stage-1 scenes are the frames at index 4
(``original``) and 3 (``previous``), each with 4 history and 8 future frames. The stage-2 scenes start 4 s later, at
frames 12 ("now") and 11 ("previous"). Their ego is shifted sideways by each of :data:`OFFSETS`, which stands in for
where a planner might have ended up. A synthetic scene pickle is the dict ``Scene.save_to_disk`` writes:

* ``scene_metadata``;
* 4 history ``frames`` with annotations in the ego frame of the frame, and the ego status in the global frame.
  Only the current frame has camera images, and there is no lidar;
* ``extended_detections_tracks``: 8 nuPlan ``DetectionsTracks`` (global boxes, t = 0.5 ... 4 s);
* ``extended_traffic_light_data``: 8 nuPlan ``TrafficLightStatuses``.

The nuPlan objects are written by :mod:`lead_s2r.formats.foreign_pickle` with nuPlan's own class paths. Synthetic tokens
have 17 hex digits, as in NAVSIM.
"""

import math
from pathlib import Path

import numpy as np
import yaml

from lead_s2r.files import write_bytes, write_text
from lead_s2r.formats.foreign_pickle import ForeignClass, ForeignObject, dumps
from lead_s2r.synthetic import navsim, navsim_map

SPLIT = "navhard_two_stage"
HISTORY, FUTURE = 4, 8
#: Current frame of each group's stage-1 "original" scene (its "previous" scene is one frame earlier).
ORIGINAL_FRAME = 4
#: Sideways shifts (m, to the ego's left) of the synthetic variants' ego.
OFFSETS = (0.0, 0.4, 1.2)

_ACTOR = "nuplan.common.actor_state"
DETECTIONS_TRACKS = ForeignClass("nuplan.planning.simulation.observation.observation_type", "DetectionsTracks")
TRACKED_OBJECTS = ForeignClass(f"{_ACTOR}.tracked_objects", "TrackedObjects")
AGENT = ForeignClass(f"{_ACTOR}.agent", "Agent")
STATIC_OBJECT = ForeignClass(f"{_ACTOR}.static_object", "StaticObject")
ORIENTED_BOX = ForeignClass(f"{_ACTOR}.oriented_box", "OrientedBox")
STATE_SE2 = ForeignClass(f"{_ACTOR}.state_representation", "StateSE2")
STATE_VECTOR_2D = ForeignClass(f"{_ACTOR}.state_representation", "StateVector2D")
SCENE_OBJECT_METADATA = ForeignClass(f"{_ACTOR}.scene_object", "SceneObjectMetadata")
TRACKED_OBJECT_TYPE = ForeignClass(f"{_ACTOR}.tracked_objects_types", "TrackedObjectType")
TRAFFIC_LIGHT_STATUSES = ForeignClass("nuplan.common.maps.maps_datatypes", "TrafficLightStatuses")
TRAFFIC_LIGHT_STATUS_DATA = ForeignClass("nuplan.common.maps.maps_datatypes", "TrafficLightStatusData")
TRAFFIC_LIGHT_STATUS_TYPE = ForeignClass("nuplan.common.maps.maps_datatypes", "TrafficLightStatusType")
#: nuPlan ``TrackedObjectType`` values of the OpenScene names: their places in the enum.
_NUPLAN_ORDER = ("vehicle", "pedestrian", "bicycle", "traffic_cone", "barrier", "czone_sign", "generic_object")
OBJECT_TYPES = {name: value for value, name in enumerate(_NUPLAN_ORDER)}
MOVING = {"vehicle", "pedestrian", "bicycle"}
RED, GREEN = 2, 0


def _token17(rng: np.random.Generator) -> str:
    return rng.bytes(9).hex()[:17]


def _global_xy(xy: np.ndarray) -> np.ndarray:
    return np.asarray(xy, np.float64) + navsim_map.ORIGIN


def tracked_object(agent: navsim.Agent, token: str, t: float, timestamp_us: int) -> ForeignObject:
    """The nuPlan ``Agent`` (moving classes) or ``StaticObject`` of ``agent`` at time ``t``, global frame."""
    centre = _global_xy(agent.centre(t))
    length, width, height = agent.size
    pose = ForeignObject(STATE_SE2, (float(centre[0]), float(centre[1]), float(agent.yaw)), reduce=True)
    box = ForeignObject(ORIENTED_BOX, (), {"_center": pose, "_length": length, "_width": width, "_height": height})
    track = {"timestamp_us": timestamp_us, "token": token[::-1], "track_id": None, "track_token": token}
    metadata = ForeignObject(SCENE_OBJECT_METADATA, (), {**track, "category_name": agent.name})
    kind = ForeignObject(TRACKED_OBJECT_TYPE, (OBJECT_TYPES[agent.name],), reduce=True)
    state = {"_box": box, "_metadata": metadata, "_tracked_object_type": kind}
    if agent.name not in MOVING:
        return ForeignObject(STATIC_OBJECT, (), state)
    velocity = ForeignObject(STATE_VECTOR_2D, tuple(float(v) for v in agent.velocity_at(t)), reduce=True)
    state |= {"_velocity": velocity, "_angular_velocity": 0.0, "_predictions": [], "_past_trajectory": None}
    return ForeignObject(AGENT, (), state)


def detections(agents: list[navsim.Agent], tokens: list[str], frame: int, timestamp_us: int) -> ForeignObject:
    """``DetectionsTracks`` of the agents seen at (fractional) log frame ``frame``."""
    t = frame * navsim.DT_US / 1e6
    seen = [
        tracked_object(agent, token, t, timestamp_us)
        for agent, token in zip(agents, tokens, strict=True)
        if agent.first <= frame <= agent.last
    ]
    objects = ForeignObject(TRACKED_OBJECTS, (), {"tracked_objects": seen})
    return ForeignObject(DETECTIONS_TRACKS, (), {"tracked_objects": objects})


def traffic_light_statuses(frame: int, timestamp_us: int) -> ForeignObject:
    statuses = []
    for connector, red in navsim.traffic_lights(frame):
        status = ForeignObject(TRAFFIC_LIGHT_STATUS_TYPE, (RED if red else GREEN,), reduce=True)
        state = {"status": status, "lane_connector_id": int(connector), "timestamp": timestamp_us}
        statuses.append(ForeignObject(TRAFFIC_LIGHT_STATUS_DATA, (), state))
    return ForeignObject(TRAFFIC_LIGHT_STATUSES, (), {"traffic_lights": statuses})


def shifted_pose(pose: np.ndarray, offset: float) -> np.ndarray:
    """``pose`` (local map frame) moved ``offset`` metres to its left."""
    return pose + np.array([-math.sin(pose[2]) * offset, math.cos(pose[2]) * offset, 0.0])


def synthetic_scene(
    out: Path, spec: navsim.LogSpec, log_frames: list[dict], start: int, offset: float, rng: np.random.Generator
) -> str:
    """Write the synthetic scene now at log frame ``start``, its ego ``offset`` m to the left; return its token."""
    states = navsim.ego_states(spec)
    agents = navsim.agents_for(spec, states["poses"][0])
    tokens = next(list(f["anns"]["track_tokens"]) for f in log_frames if len(f["anns"]["track_tokens"]) == len(agents))
    initial = _token17(rng)
    t0_us = int(log_frames[0]["timestamp"])
    frames = []
    for frame in range(start - HISTORY + 1, start + 1):
        pose = shifted_pose(states["poses"][frame], offset)
        vx, vy, ax, ay = states["dynamics"][frame]
        anns = navsim.annotations(agents, frame, pose, tokens)
        cameras = {name.lower(): {} for name in navsim.CAMERAS}  # images in the current frame only
        if frame == start:
            for name in navsim.CAMERAS:
                blob = f"{spec.name}/{name}/{initial}_{name.lower()}.jpg"
                navsim.write_jpeg(out / SPLIT / "sensor_blobs" / blob, navsim.render_camera(name, pose, anns, rng))
                cameras[name.lower()] = {"data_path": blob, **navsim.camera_calibration(name)}
        frames.append(
            {
                "token": initial if frame == start else _token17(rng),
                "timestamp": t0_us + frame * navsim.DT_US,
                "roadblock_ids": list(spec.roadblocks),
                "traffic_lights": navsim.traffic_lights(frame),
                "annotations": {
                    "boxes": anns["gt_boxes"],
                    "names": list(anns["gt_names"]),
                    "velocity_3d": anns["gt_velocity_3d"],
                    "instance_tokens": list(anns["instance_tokens"]),
                    "track_tokens": list(anns["track_tokens"]),
                },
                "ego_status": {
                    "ego_pose": np.r_[_global_xy(pose[:2]), pose[2]].astype(np.float64),
                    "ego_velocity": np.array([vx, vy], np.float32),
                    "ego_acceleration": np.array([ax, ay], np.float32),
                    "driving_command": np.array(spec.command, np.int64),
                    "in_global_frame": True,
                },
                "lidar_path": None,
                "camera_dict": cameras,
            }
        )
    future = range(start + 1, start + FUTURE + 1)
    scene = {
        "scene_metadata": {
            "log_name": spec.name,
            "scene_token": initial,
            "map_name": navsim_map.LOCATION,
            "initial_token": initial,
            "num_history_frames": HISTORY,
            "num_future_frames": FUTURE,
            "corresponding_original_scene": log_frames[start]["token"],  # the last frame of the stage-1 scene
            "corresponding_original_initial_token": log_frames[start - FUTURE]["token"],
        },
        "frames": frames,
        "extended_traffic_light_data": [traffic_light_statuses(f, t0_us + f * navsim.DT_US) for f in future],
        "extended_detections_tracks": [detections(agents, tokens, f, t0_us + f * navsim.DT_US) for f in future],
    }
    write_bytes(out / SPLIT / "synthetic_scene_pickles" / f"{initial}.pkl", dumps(scene))
    return initial


def write_configs(out: Path, logs: dict[str, list[dict]], mapping: list) -> None:
    """The split's scene filter and train/test-split yamls, as NAVSIM's config folders lay them out."""
    stage_one = [token for original, previous, _ in mapping for token in (original, previous)]
    synthetic = [token for *_, pairs in mapping for pair in pairs for token in pair]
    scene_filter = navsim.scene_filter(logs, stage_one, HISTORY, FUTURE, include_synthetic_scenes=True)
    scene_filter["reactive_synthetic_initial_tokens"] = synthetic
    split = {"defaults": [{"scene_filter": SPLIT}], "data_split": SPLIT, "reactive_all_mapping": mapping}
    for folder, config in (("scene_filters", scene_filter), ("train_test_split", split)):
        write_text(out / folder / f"{SPLIT}.yaml", yaml.safe_dump(config, sort_keys=False))


def generate(out: Path, count: int | None = None, seed: int = 0) -> None:
    """Write the split described in the module docstring with ``count`` logs (default 3), one group each."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    navsim_map.write_map(out / "maps")
    logs, mapping = {}, []
    for spec in navsim.log_specs(count, seed):
        frames = navsim.write_log(out, spec, rng, out / SPLIT / "openscene_meta_datas", out / SPLIT / "sensor_blobs")
        logs[spec.name] = frames
        pairs = [  # per offset: the scene now and the one a frame before
            [synthetic_scene(out, spec, frames, ORIGINAL_FRAME + FUTURE - back, offset, rng) for back in (0, 1)]
            for offset in OFFSETS
        ]
        mapping.append([frames[ORIGINAL_FRAME]["token"], frames[ORIGINAL_FRAME - 1]["token"], pairs])
    write_configs(out, logs, mapping)
