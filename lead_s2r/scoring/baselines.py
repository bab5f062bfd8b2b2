"""Model-free planners: the floor any learned policy has to beat, and a quick way to exercise the scorers."""

from typing import Any

import numpy as np

from lead_s2r.predictions import Prediction, PredictionError
from lead_s2r.schema import check_trajectory
from lead_s2r.scoring.navsim_grid import NAVSIM_GRID


def constant_turn_rate(speed: float, yaw_rate: float, t: np.ndarray) -> np.ndarray:
    """Poses [x, y, yaw] (T, 3) of an ego that keeps its speed and yaw rate (CTRV), from the origin at t = 0."""
    t = np.asarray(t, np.float64)
    yaw = yaw_rate * t
    if abs(yaw_rate) < 1e-6:
        return np.stack([speed * t, np.zeros_like(t), yaw], axis=1)
    radius = speed / yaw_rate
    return np.stack([radius * np.sin(yaw), radius * (1.0 - np.cos(yaw)), yaw], axis=1)


#: The horizon each benchmark scores (NAVSIM's HumanAgent replays 4 s, WOD-E2E's RFS scores 5 s); other datasets
#: replay their whole logged future.
SCORED_HORIZON_S = {"navsim": 4.0, "wod_e2e": 5.0}


def predict_human(sample: dict[str, Any], horizon: float | None = None) -> Prediction:
    """The logged future up to ``horizon`` seconds, by default the horizon its benchmark scores (NAVSIM's
    HumanAgent; the paper's "Expert" row)."""
    if "future" not in sample:
        raise PredictionError(
            f"sample {sample['__key__']!r} ({sample['meta']['dataset']}/{sample['meta']['split']}) has no logged "
            "future for the human planner to replay; score a split with futures, or --planner constant-velocity"
        )
    future = np.asarray(sample["future"], np.float64)
    check_trajectory(sample["__key__"], "future", future, past=False)  # a damaged future is the data's fault
    if horizon is None:
        horizon = SCORED_HORIZON_S.get(sample["meta"]["dataset"], float(future[-1, 0]))
    kept = future[future[:, 0] <= horizon + 1e-3]
    return Prediction(
        sample["__key__"], sample["meta"]["dataset"], kept[:, 0].astype(np.float32), kept[:, 1:3], kept[:, 3]
    )


def predict_constant_velocity(sample: dict[str, Any], t: np.ndarray = NAVSIM_GRID) -> Prediction:
    """NAVSIM's ConstantVelocityAgent: straight ahead at the current speed, heading kept (no turn rate)."""
    poses = constant_turn_rate(float(np.hypot(*sample["meta"]["ego"]["velocity"])), 0.0, t)
    key, dataset = sample["__key__"], sample["meta"]["dataset"]
    return Prediction(key, dataset, np.asarray(t, np.float32), poses[:, :2], poses[:, 2])


#: ``lead-s2r score --planner NAME``: model-free planners that predict from a converted sample.
PLANNERS = {"human": predict_human, "constant-velocity": predict_constant_velocity}
#: the sample field a planner cannot predict without (a sample lacking it is left unpredicted, e.g. WOD-E2E's test).
PLANNER_NEEDS = {"human": "future"}
