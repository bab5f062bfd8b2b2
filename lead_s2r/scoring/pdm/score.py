"""NAVSIM v1.1 PDMS of simulated ego states (``score_states``) and of planner proposals (``score_proposals``).

``score_states`` is ``PDMScorer.score_proposals`` over any number of rows at once; ``score_proposals`` is
``navsim.evaluate.pdm_score`` for a whole candidate set: the reference (PDM-Closed) and every proposal are
interpolated to 41 states, simulated together and scored in one pass, and each proposal's EP is normalised over
``[reference, proposal]`` exactly as one ``pdm_score`` call per proposal would. Map and observation are built once
per scene (pass them in to reuse them across calls). The rules and constants are in the sub-metric modules.
"""

from typing import Any

import numpy as np
import shapely

from lead_s2r.scoring.pdm.collisions import TTC_OFFSETS, enclosing_radius, no_at_fault_collisions, time_to_collision
from lead_s2r.scoring.pdm.comfort import comfort
from lead_s2r.scoring.pdm.footprint import Corner, ego_coords
from lead_s2r.scoring.pdm.map_flags import DrivableMap, ego_areas
from lead_s2r.scoring.pdm.metrics import (
    drivable_area_compliance,
    driving_direction_compliance,
    ego_progress,
    pdms_v11,
    progress_along,
)
from lead_s2r.scoring.pdm.observation import Observation, log_observation
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex

METRIC = "pdms@navsim-1.1"
INTERVAL_S = 0.1
REFERENCE_INTERVAL_S = 0.1
COLUMNS = (
    "no_at_fault_collisions",
    "drivable_area_compliance",
    "driving_direction_compliance",
    "ego_progress",
    "time_to_collision_within_bound",
    "comfort",
    "score",
    "progress_m",
    "ep_normaliser_m",
    "collision_time_idx",
    "ttc_time_idx",
)


def _centerline(scene: PDMScene) -> shapely.LineString:
    centerline = np.asarray(scene.centerline, np.float64)
    if centerline.ndim != 2 or len(centerline) < 2 or not np.isfinite(centerline[:, :2]).all():
        raise ValueError(
            f"scene {scene.key!r}: centerline needs at least 2 finite (x, y, heading) rows, got shape "
            f"{centerline.shape}; EP is measured along it (rebuild the scene's route)"
        )
    return shapely.linestrings(centerline[:, :2])


def _check_states(scene: PDMScene, states: np.ndarray, observation: Observation) -> None:
    if states.ndim != 3 or states.shape[-1] != STATE_SIZE or states.shape[1] < 2:
        raise ValueError(f"scene {scene.key!r}: states must be (N, T, {STATE_SIZE}), got {states.shape}")
    if not np.isfinite(states).all():
        raise ValueError(f"scene {scene.key!r}: simulated states hold NaN or inf")
    needed = states.shape[1] + max(TTC_OFFSETS)
    if observation.num_steps < needed:
        raise ValueError(
            f"scene {scene.key!r}: the observation has {observation.num_steps} steps, TTC over {states.shape[1]} "
            f"states needs {needed} (build it with log_observation(scene, num_steps={needed}))"
        )


def score_states(
    scene: PDMScene,
    states: np.ndarray,
    observation: Observation,
    ep_reference: int | None,
    *,
    drivable_map: DrivableMap | None = None,
) -> dict[str, np.ndarray]:
    """Sub-scores of simulated rear-axle states ``(N, 41, 11)`` in the scene frame: one entry per row for every
    column of :data:`COLUMNS` (indices -1 where nothing happened), plus the ``(N, 41)`` flags ``multiple_lanes``,
    ``non_drivable_area`` and ``oncoming_traffic``. ``ep_reference`` picks EP's normalisation (see
    :func:`~lead_s2r.scoring.pdm.metrics.ego_progress`)."""
    states = np.asarray(states, np.float64)
    _check_states(scene, states, observation)
    drivable_map = DrivableMap.from_scene(scene) if drivable_map is None else drivable_map
    coords = ego_coords(states, scene.vehicle)
    radius = enclosing_radius(scene.vehicle.length, scene.vehicle.width)
    rear_axles = states[..., StateIndex.X : StateIndex.Y + 1]
    areas = ego_areas(drivable_map, coords, rear_axles, np.asarray(scene.route_lane_ids, np.int64))
    lanes_or_off_road = areas.multiple_lanes | areas.non_drivable_area

    nc, collision_idx = no_at_fault_collisions(states, coords, radius, observation, lanes_or_off_road)
    dac = drivable_area_compliance(areas.non_drivable_area)
    centers = coords[:, :, Corner.CENTER]
    ddc = driving_direction_compliance(centers, areas.oncoming_traffic, INTERVAL_S)
    progress = progress_along(_centerline(scene), centers[:, 0], centers[:, -1])
    ep, normaliser = ego_progress(progress, np.stack([nc, dac]).prod(axis=0), ep_reference)
    ttc, ttc_idx = time_to_collision(
        states, coords, radius, observation, lanes_or_off_road, areas.rear_axle_in_intersection, INTERVAL_S
    )
    c = comfort(states, INTERVAL_S)
    return {
        "no_at_fault_collisions": nc,
        "drivable_area_compliance": dac,
        "driving_direction_compliance": ddc,
        "ego_progress": ep,
        "time_to_collision_within_bound": ttc,
        "comfort": c,
        "score": pdms_v11(nc, dac, ep, ttc, c, ddc),
        "progress_m": progress,
        "ep_normaliser_m": normaliser,
        "collision_time_idx": collision_idx,
        "ttc_time_idx": ttc_idx,
        "multiple_lanes": areas.multiple_lanes,
        "non_drivable_area": areas.non_drivable_area,
        "oncoming_traffic": areas.oncoming_traffic,
    }


def _poses(scene: PDMScene, poses: Any, name: str, dims: str) -> np.ndarray:
    """``poses`` as float64 with the axes named in ``dims`` (ending in 3) and only finite values."""
    array = np.asarray(poses, np.float64)
    if array.ndim != len(dims.split(",")) or array.shape[-1] != 3 or array.shape[-2] < 1:
        raise ValueError(f"scene {scene.key!r}: {name} must be ({dims}) ego-frame poses, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"scene {scene.key!r}: {name} holds NaN or inf poses; the planner's output is invalid here")
    return array


def score_proposals(
    scene: PDMScene,
    proposals: np.ndarray,
    interval: float,
    reference: np.ndarray | None = None,
    metric: str = METRIC,
    *,
    observation: Observation | None = None,
    drivable_map: DrivableMap | None = None,
) -> dict[str, np.ndarray]:
    """PDMS v1.1 of ``proposals (N, K, 3)`` (ego-frame poses at ``interval * (k + 1)``), one row each, with the
    columns of :data:`COLUMNS`. ``reference (M, 3)``: the EP normaliser's trajectory at 0.1 s steps from t = 0 (row 0
    is the initial pose); None plans it with PDM-Closed. The scene's ``t0_us`` (when known) reproduces NAVSIM's
    microsecond truncation of the interpolation times (see ``interpolation``)."""
    if metric != METRIC:
        raise ValueError(f"metric {metric!r} is not scored here; score_proposals computes {METRIC!r}")
    proposals = _poses(scene, proposals, "proposals", "N, K, 3")
    if reference is None:
        from lead_s2r.scoring.pdm.pdm_closed import plan_reference

        reference = plan_reference(scene)
    reference = _poses(scene, reference, "reference", "M, 3")
    if len(reference) < 2:
        raise ValueError(f"scene {scene.key!r}: reference needs poses after t = 0, got shape {reference.shape}")
    from lead_s2r.scoring.pdm.interpolation import interpolate_proposals, interpolate_reference
    from lead_s2r.scoring.pdm.simulation import simulate_proposals

    targets = np.concatenate(
        [
            interpolate_reference(reference, REFERENCE_INTERVAL_S, scene.t0_us)[None],
            interpolate_proposals(proposals, interval, scene.t0_us),
        ]
    )
    states = simulate_proposals(
        targets, scene.ego_velocity, scene.ego_acceleration, scene.tire_steering_angle, scene.vehicle
    )
    observation = log_observation(scene) if observation is None else observation
    scores = score_states(scene, states, observation, ep_reference=0, drivable_map=drivable_map)
    return {name: scores[name][1:] for name in COLUMNS}
