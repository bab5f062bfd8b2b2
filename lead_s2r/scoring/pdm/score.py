"""NAVSIM's PDM score of simulated ego states (``score_states``: PDMS v1.1, ``score_states_v2``: EPDMS v2.2 before
the human filter) and of planner proposals (``score_proposals``, either metric).

``score_states`` is ``PDMScorer.score_proposals`` over any number of rows at once; ``score_proposals`` is
``navsim.evaluate.pdm_score`` for a whole candidate set: the reference (PDM-Closed) and every proposal are
interpolated to 41 states, simulated together and scored in one pass, and each proposal's EP is normalised over
``[reference, proposal]`` exactly as one ``pdm_score`` call per proposal would. Map and observation are built once
per scene (pass them in to reuse them across calls).

v2.2 (``epdms@navsim-2.2``) shares simulation, footprints, map flags, NC, DAC and the collision walk with v1.1 and
differs in: the log-replay observation (41 steps, tracks overlapping the ego at t0 removed), TTC over steps 0..31,
DDC as a multiplier with intersection steps zeroed, TLC, LK, HC instead of C, the unmasked EP, then the human
penalty filter and EC (``epdms.py``). The human trajectory is simulated in the same batch as the proposals (every
row is simulated and scored independently) and scored as NAVSIM scores it, alone and without a past: its EP and HC
are 1 by construction, so only its NC, DAC, DDC, TLC, TTC and LK can filter. EC compares each proposal's simulation
with that of the plan made ``frame_gap`` earlier (``PreviousFrame``), simulated from the ego state there; without a
previous frame EC is NaN and the final score drops its weight.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.collisions import TTC_OFFSETS, no_at_fault_collisions, step_hits, time_to_collision
from lead_s2r.scoring.pdm.comfort import comfort, extended_comfort_features, history_comfort
from lead_s2r.scoring.pdm.extended_comfort import two_frame_extended_comfort
from lead_s2r.scoring.pdm.footprint import Corner, ego_coords, heading_directions
from lead_s2r.scoring.pdm.interpolation import interpolate_proposals, interpolate_reference
from lead_s2r.scoring.pdm.map_flags import DrivableMap, EgoAreas, ego_areas
from lead_s2r.scoring.pdm.metrics import (
    drivable_area_compliance,
    driving_direction_compliance,
    ego_progress,
    ego_progress_v2,
    first_step,
    lane_keeping,
    pdms_v11,
    progress_along,
)
from lead_s2r.scoring.pdm.observation import V2_STEPS, Observation, log_observation
from lead_s2r.scoring.pdm.scene import PDMScene, PreviousFrame
from lead_s2r.scoring.pdm.simulation import simulate_proposals
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex
from lead_s2r.scoring.pdm.traffic_lights import on_red_light, red_light_polygons, traffic_light_compliance

METRIC = "pdms@navsim-1.1"
EPDMS_METRIC = "epdms@navsim-2.2"
METRICS = (METRIC, EPDMS_METRIC)
INTERVAL_S = 0.1
#: the columns after the sub-scores: EP's metres, and the 0.1 s step where NC, TTC and DAC failed and the agent row NC
#: hit (-1: they did not), so a report can say when a sub-score was lost and to whom
PROGRESS_COLUMNS = ("progress_m", "ep_normaliser_m")
STEP_COLUMNS = ("collision_time_idx", "ttc_time_idx", "dac_time_idx", "collision_object_idx")
DIAGNOSTICS = (*PROGRESS_COLUMNS, *STEP_COLUMNS)
#: ``pdms@navsim-1.1`` columns: NAVSIM's names of the sub-scores (v1.1's comfort), the score, the diagnostics
COLUMNS = (epdms.NC, epdms.DAC, epdms.DDC, epdms.EP, epdms.TTC, "comfort", "score", *DIAGNOSTICS)
#: ``epdms@navsim-2.2`` columns: NAVSIM v2's names (after the human filter, ``score`` = final EPDMS) + v1.1's
#: diagnostics and the step where LK failed
EPDMS_COLUMNS = (*epdms.SUB_SCORES, "score", *DIAGNOSTICS, "lane_keeping_fail_idx")


def _centerline(scene: PDMScene) -> shapely.LineString:
    centerline = np.asarray(scene.centerline, np.float64)
    if centerline.ndim != 2 or len(centerline) < 2 or not np.isfinite(centerline[:, :2]).all():
        raise ValueError(
            f"scene {scene.key!r}: centerline needs at least 2 finite (x, y, heading) rows, got shape "
            f"{centerline.shape}; EP is measured along it (rebuild the scene's route)"
        )
    return shapely.linestrings(centerline[:, :2])


def _check_states(scene: PDMScene, states: np.ndarray, observation: Observation, lookahead: int) -> None:
    if states.ndim != 3 or states.shape[-1] != STATE_SIZE or states.shape[1] < 2:
        raise ValueError(f"scene {scene.key!r}: states must be (N, T, {STATE_SIZE}), got {states.shape}")
    if not np.isfinite(states).all():
        raise ValueError(f"scene {scene.key!r}: simulated states hold NaN or inf")
    needed = states.shape[1] + lookahead
    if observation.num_steps < needed:
        raise ValueError(
            f"scene {scene.key!r}: the observation has {observation.num_steps} steps, TTC over {states.shape[1]} "
            f"states needs {needed} (build it with log_observation(scene, num_steps={needed}))"
        )


@dataclass
class _Prelude:
    """What v1.1 and v2.2 score alike before they part."""

    states: np.ndarray
    coords: np.ndarray  # (N, T, 5, 2)
    along: tuple[np.ndarray, np.ndarray]  # cosine and sine of the headings (N, T), for TTC's moves
    radius: float
    areas: EgoAreas
    lanes_or_off_road: np.ndarray  # (N, T) MULTIPLE_LANES or NON_DRIVABLE_AREA: where NC and TTC fault more
    hits: tuple[np.ndarray, np.ndarray]
    nc: np.ndarray
    collision_idx: np.ndarray
    collision_object: np.ndarray
    dac: np.ndarray
    centerline: shapely.LineString
    progress: np.ndarray

    @property
    def centers(self) -> np.ndarray:
        return self.coords[:, :, Corner.CENTER]

    def time_to_collision(
        self, observation: Observation, num_steps: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """TTC and its first violating step over the first ``num_steps`` states (all: None)."""
        return time_to_collision(
            self.states, self.coords, self.radius, observation, self.lanes_or_off_road,
            self.areas.rear_axle_in_intersection, INTERVAL_S, num_steps=num_steps, hits_at_rest=self.hits,
            along=self.along,
        )  # fmt: skip


def _prelude(
    scene: PDMScene, states: np.ndarray, observation: Observation, lookahead: int, drivable_map: DrivableMap | None
) -> _Prelude:
    states = np.asarray(states, np.float64)
    _check_states(scene, states, observation, lookahead)
    drivable_map = DrivableMap.from_scene(scene) if drivable_map is None else drivable_map
    along = heading_directions(states)
    coords = ego_coords(states, scene.vehicle, along)
    rear_axles = states[..., StateIndex.X : StateIndex.Y + 1]
    areas = ego_areas(drivable_map, coords, rear_axles, np.asarray(scene.route_lane_ids, np.int64))
    radius = float(np.hypot(scene.vehicle.length / 2.0, scene.vehicle.width / 2.0))  # a circle holding the box
    hits = step_hits(coords, radius, observation)
    lanes_or_off_road = areas.multiple_lanes | areas.non_drivable_area
    nc, step, hit = no_at_fault_collisions(states, coords, hits, observation, lanes_or_off_road)
    dac = drivable_area_compliance(areas.non_drivable_area)
    centerline = _centerline(scene)
    progress = progress_along(centerline, coords[:, 0, Corner.CENTER], coords[:, -1, Corner.CENTER])
    return _Prelude(
        states, coords, along, radius, areas, lanes_or_off_road, hits, nc, step, hit, dac, centerline, progress
    )


def score_states(
    scene: PDMScene,
    states: np.ndarray,
    observation: Observation,
    ep_reference: int | None,
    *,
    drivable_map: DrivableMap | None = None,
) -> dict[str, np.ndarray]:
    """Sub-scores of simulated rear-axle states ``(N, 41, 11)`` in the scene frame, by :data:`COLUMNS` (indices -1
    where nothing happened) and the ``(N, 41)`` area flags. ``ep_reference`` picks EP's normalisation (see
    :func:`~lead_s2r.scoring.pdm.metrics.ego_progress`)."""
    base = _prelude(scene, states, observation, max(TTC_OFFSETS), drivable_map)
    nc, dac = base.nc, base.dac
    ddc = driving_direction_compliance(base.centers, base.areas.oncoming_traffic, INTERVAL_S)
    ep, normaliser = ego_progress(base.progress, np.stack([nc, dac]).prod(axis=0), ep_reference)
    ttc, ttc_idx = base.time_to_collision(observation)
    c = comfort(base.states, INTERVAL_S)
    return {
        "no_at_fault_collisions": nc,
        "drivable_area_compliance": dac,
        "driving_direction_compliance": ddc,
        "ego_progress": ep,
        "time_to_collision_within_bound": ttc,
        "comfort": c,
        "score": pdms_v11(nc, dac, ep, ttc, c, ddc),
        **_shared_columns(base, normaliser, ttc_idx),
    }


def _shared_columns(base: _Prelude, normaliser: np.ndarray, ttc_idx: np.ndarray) -> dict[str, np.ndarray]:
    """The columns v1.1 and v2.2 share beside their sub-scores (:data:`DIAGNOSTICS`, the ``(N, T)`` area flags)."""
    return {
        "progress_m": base.progress,
        "ep_normaliser_m": normaliser,
        "collision_time_idx": base.collision_idx,
        "ttc_time_idx": ttc_idx,
        "dac_time_idx": first_step(base.areas.non_drivable_area),
        "collision_object_idx": base.collision_object,
        "multiple_lanes": base.areas.multiple_lanes,
        "non_drivable_area": base.areas.non_drivable_area,
        "oncoming_traffic": base.areas.oncoming_traffic,
    }


def score_states_v2(
    scene: PDMScene,
    states: np.ndarray,
    observation: Observation,
    ep_reference: int | None,
    *,
    drivable_map: DrivableMap | None = None,
    red_lights: list[list[shapely.Polygon]] | None = None,
) -> dict[str, np.ndarray]:
    """v2.2 sub-scores of simulated states ``(N, 41, 11)`` *before* the human filter, as ``PDMScorer.score_proposals``
    of v2.2 leaves them, under their NAVSIM names. HC reads the scene's ``ego_past`` for every row. ``observation``:
    v2's log replay (``log_observation(scene, 41, replay=True)``); ``red_lights``: per step (``red_light_polygons``)."""
    base = _prelude(scene, states, observation, 0, drivable_map)
    nc, dac = base.nc, base.dac
    num_steps = base.states.shape[1]
    red_lights = red_light_polygons(scene, num_steps, INTERVAL_S) if red_lights is None else red_lights
    in_intersection = base.areas.center_in_intersection
    ddc = driving_direction_compliance(base.centers, base.areas.oncoming_traffic, INTERVAL_S, exclude=in_intersection)
    touching = on_red_light(base.coords, red_lights)
    tlc = traffic_light_compliance(touching)
    product = np.stack([nc, dac, ddc, tlc]).prod(axis=0)
    ep, normaliser = ego_progress_v2(base.progress, product, ep_reference)
    ttc, ttc_idx = base.time_to_collision(observation, num_steps - max(TTC_OFFSETS))
    lk, lk_idx = lane_keeping(base.centers, base.centerline, in_intersection, INTERVAL_S)
    return {
        epdms.NC: nc,
        epdms.DAC: dac,
        epdms.DDC: ddc,
        epdms.TLC: tlc,
        epdms.EP: ep,
        epdms.TTC: ttc,
        epdms.LK: lk,
        epdms.HC: history_comfort(base.states, scene.ego_past, scene.vehicle, INTERVAL_S),
        "multiplicative_metrics_prod": product,
        **_shared_columns(base, normaliser, ttc_idx),
        "lane_keeping_fail_idx": lk_idx,
        "in_intersection": in_intersection,
        "on_red_light": touching,
    }


def _poses(scene: PDMScene, poses: Any, name: str, dims: str, least: int = 1) -> np.ndarray:
    """``poses`` as float64 with the axes named in ``dims`` (ending in 3), at least ``least`` of them along the axis
    before the last, and only finite values."""
    array = np.asarray(poses, np.float64)
    if array.ndim != len(dims.split(",")) or array.shape[-1] != 3 or array.shape[-2] < least:
        raise ValueError(f"scene {scene.key!r}: {name} must be ({dims}) ego-frame poses, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"scene {scene.key!r}: {name} holds NaN or inf poses; the planner's output is invalid here")
    return array


def human_trajectory(scene: PDMScene) -> np.ndarray | None:
    """The logged future the human filter scores, or None where there is none (synthetic scenes)."""
    if scene.is_synthetic or scene.human_poses is None:
        return None
    return _poses(scene, scene.human_poses, "human_poses", "K, 3")


def simulate_rows(
    scene: PDMScene, proposals: np.ndarray, interval: float, reference: np.ndarray, human: np.ndarray | None
) -> np.ndarray:
    """The simulated states ``(rows, 41, 11)`` ``score_proposals`` scores: the reference first, then every proposal
    ``(N, K, 3)``, then the human trajectory where it is given (the human filter's). Every row is simulated on its
    own, so a row's states do not depend on the rows simulated with it."""
    targets = [
        interpolate_reference(_poses(scene, reference, "reference", "M >= 2, 3", least=2), t0_us=scene.t0_us)[None],
        interpolate_proposals(proposals, interval, scene.t0_us),
    ]
    if human is not None:
        targets.append(interpolate_proposals(human[None], scene.human_interval, scene.t0_us))
    return simulate_proposals(
        np.concatenate(targets), scene.ego_velocity, scene.ego_acceleration, scene.tire_steering_angle, scene.vehicle
    )


def score_proposals(
    scene: PDMScene,
    proposals: np.ndarray,
    interval: float,
    reference: np.ndarray,
    metric: str = METRIC,
    previous: Sequence[PreviousFrame | None] | None = None,
    *,
    observation: Observation | None = None,
    drivable_map: DrivableMap | None = None,
    red_lights: list[list[shapely.Polygon]] | None = None,
    with_states: bool = False,
    with_masked_progress: bool = False,
    human_filter: bool = True,
    simulated: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """``metric`` (PDMS v1.1 or EPDMS v2.2) of ``proposals (N, K, 3)`` (ego-frame poses at ``interval * (k + 1)``),
    one row each, with the columns of :data:`COLUMNS` or :data:`EPDMS_COLUMNS`. ``reference (M, 3)``: the EP
    normaliser's trajectory at 0.1 s steps from t = 0 (row 0 is the initial pose), e.g. PDM-Closed's
    (:func:`~lead_s2r.scoring.pdm.pdm_closed.plan_reference`, which scores its own candidates with this module).
    ``previous`` (EPDMS only): per proposal the frame before it for EC, or None (EC NaN). ``with_states`` adds the
    proposals' simulated states ``(N, 41, 11)`` as ``simulated_states`` (what two-stage EC compares, ``two_stage``);
    ``with_masked_progress`` adds EP's multiplier of each proposal (before the human filter) as
    ``progress_multiplier`` and the reference's masked progress [m] as ``reference_masked_progress_m`` (what a
    vocabulary-wide EP needs, ``vocabulary``). ``human_filter=False`` (EPDMS) leaves v2.2's human penalty filter
    out, as SimScale's vocabulary targets do. ``simulated``: :func:`simulate_rows`' rows for these proposals (a
    vocabulary simulates many chunks in one call). The scene's ``t0_us`` (when known) reproduces NAVSIM's
    microsecond truncation of the interpolation times (see ``interpolation``)."""
    if metric not in METRICS:
        raise ValueError(f"metric {metric!r} is not scored here; score_proposals computes {' and '.join(METRICS)}")
    if previous is not None and metric != EPDMS_METRIC:
        raise ValueError(f"previous frames feed EC, which {metric!r} does not have; pass previous=None")
    proposals = _poses(scene, proposals, "proposals", "N, K, 3")
    human = human_trajectory(scene) if metric == EPDMS_METRIC and human_filter else None
    if simulated is None:
        simulated = simulate_rows(scene, proposals, interval, reference, human)
    elif len(simulated) != len(proposals) + 1 + (human is not None):
        raise ValueError(
            f"scene {scene.key!r}: {len(simulated)} simulated rows for {len(proposals)} proposals; pass "
            "simulate_rows' rows (the reference, the proposals, the human trajectory where the filter scores it)"
        )
    agents = slice(1, 1 + len(proposals))
    extra = {"simulated_states": simulated[agents]} if with_states else {}
    if metric == METRIC:
        observation = log_observation(scene) if observation is None else observation
        scores = score_states(scene, simulated, observation, ep_reference=0, drivable_map=drivable_map)
        if with_masked_progress:
            extra |= _masked_progress(scores, scores[epdms.NC] * scores[epdms.DAC], agents)
        return {name: scores[name][agents] for name in COLUMNS} | extra
    observation = log_observation(scene, V2_STEPS, replay=True) if observation is None else observation
    scores = score_states_v2(
        scene, simulated, observation, ep_reference=0, drivable_map=drivable_map, red_lights=red_lights
    )
    if with_masked_progress:
        extra |= _masked_progress(scores, scores["multiplicative_metrics_prod"], agents)
    human_row = (
        None if human is None else {name: scores[name][-1] for name in epdms.FILTERED} | {epdms.EP: 1.0, epdms.HC: 1.0}
    )
    columns = epdms.human_penalty_filter({name: scores[name][agents] for name in epdms.FILTERED}, human_row)
    columns[epdms.EC] = extended_comfort(scene, simulated[agents], previous)
    columns["score"] = epdms.epdms(columns)
    return columns | {name: scores[name][agents] for name in EPDMS_COLUMNS[len(epdms.SUB_SCORES) + 1 :]} | extra


def _masked_progress(scores: dict[str, np.ndarray], multiplier: np.ndarray, agents: slice) -> dict[str, np.ndarray]:
    """EP's multiplier of the proposals, and the reference's (row 0) masked progress repeated beside them."""
    reference = scores["progress_m"][0] * multiplier[0]
    return {
        "progress_multiplier": multiplier[agents],
        "reference_masked_progress_m": np.full_like(multiplier[agents], reference),
    }


def _previous_states(scene: PDMScene, previous: PreviousFrame) -> np.ndarray:
    """The ``(41, 11)`` simulation of the previous frame's plan from its ego state, moved into the current ego frame."""
    poses = _poses(scene, np.asarray(previous.poses)[None], "previous frame poses", "1, K, 3")
    t0_us = None if scene.t0_us is None else scene.t0_us - round(previous.frame_gap * 1e6)
    targets = interpolate_proposals(poses, previous.interval, t0_us)
    states = simulate_proposals(targets, previous.ego_velocity, previous.ego_acceleration, 0.0, scene.vehicle)[0]
    x, y, heading = np.asarray(previous.ego_pose, np.float64)
    cos, sin = np.cos(heading), np.sin(heading)
    out = states.copy()
    out[:, StateIndex.X] = x + cos * states[:, StateIndex.X] - sin * states[:, StateIndex.Y]
    out[:, StateIndex.Y] = y + sin * states[:, StateIndex.X] + cos * states[:, StateIndex.Y]
    out[:, StateIndex.HEADING] = states[:, StateIndex.HEADING] + heading
    return out


def extended_comfort(
    scene: PDMScene, states: np.ndarray, previous: Sequence[PreviousFrame | None] | None
) -> np.ndarray:
    """EC ``(N,)`` of simulated states ``(N, 41, 11)`` against their previous frames (NaN where there is none)."""
    ec = np.full(len(states), np.nan)
    if previous is None:
        return ec
    if len(previous) != len(states):
        raise ValueError(
            f"scene {scene.key!r}: {len(previous)} previous frames for {len(states)} proposals; give one per "
            "proposal (None where a proposal has none)"
        )
    for row, frame in enumerate(previous):
        if frame is not None:
            before = _previous_states(scene, frame)
            ec[row] = two_frame_extended_comfort(states[row], before, frame.frame_gap, extended_comfort_features)
    return ec
