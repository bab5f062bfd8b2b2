"""A sample's bird's-eye view in the ego frame, with matplotlib: what the scorer saw and what the model planned.

The trap is the y flip: ISO 8855 has y to the left, a plot has its first axis to the right. The picture puts forward
(+x) up and left (+y) left by plotting ``(y, x)`` on an inverted horizontal axis, so a left turn bends to the left
of the picture (``tests/test_report_views.py`` checks it on the PNG's pixels).

Drawn when the sample holds them: drivable-area polygons and lane centrelines of the ``scoring`` context, lanes
with a red light at t0, agent boxes at t0 with their future tracks (numbered by agent row, the number NC's failure
names), the ego box, the logged future, the prediction(s), the PDM-Closed reference, and WOD-E2E's rater trajectories
with their scores and the RFS trust regions at the checkpoints (the box inside which a prediction keeps the rater's
score, :mod:`lead_s2r.scoring.rfs`). With ``inputs`` (``inspect --png``), also what the model reads beside the
cameras: the BEV semantic classes underneath, LiDAR points, the route and the target points.
"""

from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from lead_s2r.geometry import box_corners, raster_lookup
from lead_s2r.schema import MapKind
from lead_s2r.scoring.rfs import RFSConfig, speed_scale

LOGGED = "#00a651"
PREDICTED = "#e4007c"
COMPARED = "#1f5fd6"
REFERENCE = "#ff8c00"
RED_LIGHT = "#ff0000"
PAST = "#a0a0a0"
DRIVABLE = {MapKind.LANE, MapKind.LANE_CONNECTOR, MapKind.INTERSECTION, MapKind.CARPARK_AREA}
#: the smallest half-width of the picture [m]; it grows to hold every trajectory
MIN_HALF_RANGE_M = 20.0
#: the BEV semantic raster is resampled onto the picture at this many metres per pixel
SEMANTIC_STEP_M = 0.1
BEV_INCHES, BEV_DPI = 6.0, 100


def trajectory_colors(labels: list[str]) -> dict[str, str]:
    """The colour of each trajectory label: past, logged and reference fixed, predictions in the order given."""
    fixed = {"past": PAST, "logged": LOGGED, "reference": REFERENCE}
    predictions = iter([PREDICTED, COMPARED] * len(labels))
    return {label: fixed[label] if label in fixed else next(predictions) for label in labels}


def plot_xy(axes: Any, xy: np.ndarray, *args: Any, **kwargs: Any) -> None:
    """Plot ego-frame ``(N, 2)`` points: x up, y left (the horizontal axis is inverted)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    axes.plot(xy[:, 1], xy[:, 0], *args, **kwargs)


def _fill(axes: Any, xy: np.ndarray, **kwargs: Any) -> None:
    axes.add_patch(Polygon(np.asarray(xy, np.float64)[:, ::-1], closed=True, **kwargs))


def pieces(flat: Any, offsets: Any) -> list[np.ndarray]:
    """A ragged field of the ``scoring`` context (flat points, offsets) as one array of points per piece."""
    return [np.asarray(flat, np.float64)[a:b] for a, b in pairwise(np.asarray(offsets).tolist())]


def _map(axes: Any, scoring: dict[str, np.ndarray]) -> None:
    """Drivable polygons, centrelines and the lanes under a red light at the step nearest t0."""
    polygons = pieces(scoring["polygon_xy"], scoring["polygon_offsets"])
    for polygon, kind in zip(polygons, np.asarray(scoring["polygon_kind"]), strict=True):
        drivable = int(kind) in DRIVABLE
        _fill(axes, polygon, facecolor="#d9d9d9" if drivable else "#eef3e8", edgecolor="#b0b0b0", linewidth=0.5)
    lines = pieces(scoring["centerline_xy"], scoring["centerline_offsets"])
    red = set()
    if len(scoring.get("red_light_t", ())):
        step = int(np.argmin(np.abs(np.asarray(scoring["red_light_t"]))))
        offsets = np.asarray(scoring["red_light_offsets"])
        red = set(np.asarray(scoring["red_light_ids"])[offsets[step] : offsets[step + 1]].tolist())
    for line, lane in zip(lines, np.asarray(scoring["centerline_id"]).tolist(), strict=True):
        if lane in red:
            plot_xy(axes, line, color=RED_LIGHT, linewidth=3, label="red light")
        else:
            plot_xy(axes, line, "--", color="#909090", linewidth=0.7)


def _agents(axes: Any, sample: dict[str, Any]) -> None:
    boxes = np.asarray(sample.get("boxes", np.zeros((0, 10))), np.float64).reshape(-1, 10)
    for index, corners in enumerate(box_corners(boxes)):
        _fill(axes, corners, facecolor="none", edgecolor="#3b3b3b", linewidth=1.2)
        axes.annotate(str(index), (boxes[index, 1], boxes[index, 0]), fontsize=8, color="#3b3b3b", clip_on=True)
    future = sample.get("agents_future")
    if future is not None:
        poses, valid = np.asarray(future["poses"]), np.asarray(future["valid"], bool)
        for index, (track, ok) in enumerate(zip(poses, valid, strict=True)):
            plot_xy(axes, track[ok, :2], ":", color="#6b6b6b", linewidth=1)
            if index >= len(boxes) and ok.any():  # an agent that appears later: numbered where it appears
                first = track[ok][0]
                axes.annotate(str(index), (first[1], first[0]), fontsize=8, color="#6b6b6b", clip_on=True)


def _ego(axes: Any, sample: dict[str, Any]) -> None:
    vehicle = sample["meta"]["vehicle"]
    box = np.array([[vehicle["rear_axle_to_center"], 0, 0, vehicle["length"], vehicle["width"], 0, 0, 0, 0, 0]])
    _fill(axes, box_corners(box)[0], facecolor="#4a4a4a", edgecolor="black", linewidth=1)


def trust_region(rater: np.ndarray, index: int, checkpoint: int, speed: float, config: RFSConfig) -> np.ndarray:
    """The corners ``(4, 2)`` of RFS's trust region around waypoint ``index`` of a rater ``(T, 2)`` at checkpoint
    ``checkpoint``: half-lengths are the speed-scaled lateral and longitudinal thresholds, along the rater's
    direction of travel there (backward difference, as the metric takes it)."""
    base = config.base_thresholds[checkpoint] * float(speed_scale(np.asarray(speed), config))
    lateral, longitudinal = base * config.lat_lng_multipliers[0], base * config.lat_lng_multipliers[1]
    step = rater[index] - rater[index - 1] if index > 0 else rater[index]
    along = step / max(float(np.linalg.norm(step)), 1e-9)
    across = np.array([-along[1], along[0]])
    signs = ((1, 1), (1, -1), (-1, -1), (-1, 1))
    return np.array([rater[index] + a * longitudinal * along + b * lateral * across for a, b in signs])


def _raters(axes: Any, sample: dict[str, Any]) -> None:
    raters = sample["raters"]
    config = RFSConfig()
    speed = float(sample["meta"]["ego"]["speed"])
    for trajectory, score, length in zip(raters["trajectories"], raters["scores"], raters["lengths"], strict=True):
        points = np.asarray(trajectory, np.float64)[: int(length)]
        plot_xy(axes, points, "-", color="#8a5cc7", linewidth=1.5, alpha=0.9, label="raters (score at the end)")
        axes.annotate(f"{float(score):g}", (points[-1, 1], points[-1, 0]), color="#5b2d9e", fontsize=8)
        for checkpoint, index in enumerate(config.checkpoint_indices.tolist()):
            if index < len(points):
                corners = trust_region(points, index, checkpoint, speed, config)
                _fill(axes, corners, facecolor="#8a5cc780", edgecolor="#5b2d9e", linewidth=0.8)


def _limits(axes: Any, trajectories: dict[str, np.ndarray]) -> None:
    points = [np.asarray(xy, np.float64).reshape(-1, 2) for xy in trajectories.values()]
    points = np.vstack([np.zeros((1, 2)), *points])
    points = points[np.isfinite(points).all(axis=1)]
    centre = (points.max(axis=0) + points.min(axis=0)) / 2
    half = max(MIN_HALF_RANGE_M, float((points.max(axis=0) - points.min(axis=0)).max()) / 2 + 5.0)
    axes.set_ylim(centre[0] - half, centre[0] + half)
    axes.set_xlim(centre[1] + half, centre[1] - half)  # inverted: +y (left) on the left


def _semantic(axes: Any, sample: dict[str, Any]) -> None:
    """The stored BEV semantic raster resampled onto the axes' limits, a colour per class, class 0 (unlabeled) clear."""
    (y_left, y_right), (x_bottom, x_top) = axes.get_xlim(), axes.get_ylim()
    x = np.arange(x_top, x_bottom, -SEMANTIC_STEP_M) - SEMANTIC_STEP_M / 2
    y = np.arange(y_left, y_right, -SEMANTIC_STEP_M) - SEMANTIC_STEP_M / 2
    labels = raster_lookup(
        sample["bev_semantic"], sample["meta"]["bev"]["pixel_to_ego"], *np.meshgrid(x, y, indexing="ij"), fill=0
    )
    classes = np.ma.masked_equal(np.clip(labels, 0, 15), 0)
    extent = (y_left, y_right, x_bottom, x_top)
    axes.imshow(classes, cmap="turbo", vmin=0, vmax=15, alpha=0.35, extent=extent, interpolation="nearest", zorder=0)


def _inputs(axes: Any, sample: dict[str, Any]) -> None:
    if "bev_semantic" in sample and "pixel_to_ego" in sample["meta"].get("bev", {}):
        _semantic(axes, sample)
    if "lidar" in sample:
        plot_xy(axes, sample["lidar"][:, :2], ",", color="#9a9a9a", zorder=0.5)
    if "route" in sample:
        plot_xy(axes, sample["route"], "-", color="#2896e6", linewidth=1.5, label="route")
    points = np.asarray(sample.get("target_points", np.zeros((0, 2))), np.float64)
    points = points[np.isfinite(points).all(axis=1)]  # absent ones are NaN rows
    if len(points):
        plot_xy(axes, points, "o", color="#e62828", markersize=7, linestyle="none", label="target points")


def draw_bev(axes: Any, sample: dict[str, Any], trajectories: dict[str, np.ndarray], inputs: bool = False) -> None:
    """The BEV of ``sample`` on ``axes`` with ``{label: (T, 2) ego-frame xy}`` drawn on top (``past``, ``logged``,
    ``reference`` or a prediction's label; colours by :func:`trajectory_colors`), and with ``inputs`` the model's
    inputs beside the cameras underneath. Axes are metres, forward up, left left."""
    if "scoring" in sample:
        _map(axes, sample["scoring"])
    _agents(axes, sample)
    if "raters" in sample:
        _raters(axes, sample)
    _ego(axes, sample)
    colors = trajectory_colors(list(trajectories))
    for label, xy in trajectories.items():
        plot_xy(axes, xy, "o-", color=colors[label], linewidth=2, markersize=3, label=label)
    _limits(axes, trajectories)
    if inputs:
        _inputs(axes, sample)
    axes.set_aspect("equal")
    axes.set_xlabel("y [m] (left is left)")
    axes.set_ylabel("x [m] (forward is up)")
    handles, labels = axes.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    if unique:
        axes.legend(unique.values(), unique.keys(), loc="lower right", fontsize=7)


def bev_figure(sample: dict[str, Any], trajectories: dict[str, np.ndarray], title: str = "") -> Figure:
    """:func:`draw_bev` as a figure of its own, the report's picture of a sample."""
    figure = Figure(figsize=(BEV_INCHES, BEV_INCHES), dpi=BEV_DPI)
    axes = figure.add_axes((0.1, 0.08, 0.85, 0.85))
    draw_bev(axes, sample, trajectories)
    axes.set_title(title, fontsize=9)
    return figure


def save_figure(figure: Figure, out: str | Path) -> None:
    """Write a figure as PNG at its own size (no tight bounding box, so pixels stay where the axes put them)."""
    figure.savefig(out, format="png")
