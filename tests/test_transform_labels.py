"""The per-sample label functions of the training transform against their plain definitions, bit for bit.

The references here are the straightforward forms the fast code replaced (one rotation of every (box, point) pair,
``nan_to_num`` and a float32 cast, ``np.linalg.norm`` of the route's steps); the LiDAR reference lives in
test_transform_speed.py (LEAD's CenterNet encoding is checked in test_lead_labels.py). The inputs aim at the paths the
fast code adds: LiDAR points on cell edges and off the grid (NaN, inf, overflow), radar points on the grown
footprint's edge.
"""

import numpy as np
import pytest
import torch
from test_transform_speed import random_boxes, reference_lidar
from tiny_models import sensor_spec

from lead_s2r.data.lead_labels import RADAR_PRIORITY, LeadBoxClass, radar_priority
from lead_s2r.data.lead_route import _dot_sign, lead_route
from lead_s2r.data.lidar import rasterize_lidar
from lead_s2r.data.radar import MAX_RADAR_TARGETS, RADAR_HIT_MARGIN_M, radar_targets
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.geometry import resample, rotate
from lead_s2r.models.config import CARLA_BEV, BEVGrid
from lead_s2r.models.inputs import lidar_input
from lead_s2r.schema import command4

# --------------------------------------------------------------------------- references


def reference_radar_targets(radar: np.ndarray, boxes: np.ndarray) -> dict[str, np.ndarray]:
    targets, valid = np.zeros((MAX_RADAR_TARGETS, 3), np.float32), np.zeros(MAX_RADAR_TARGETS, bool)
    if len(radar) and len(boxes):
        local = rotate(radar[None, :, :2] - boxes[:, None, :2], -boxes[:, None, 6])  # (boxes, points, 2)
        half = boxes[:, None, 3:5] / 2 + RADAR_HIT_MARGIN_M
        hit = (np.abs(local) <= half).all(axis=-1).any(axis=1)
        speed = np.hypot(boxes[:, 7], boxes[:, 8])
        chosen = np.flatnonzero(hit)[np.argsort(-speed[hit], kind="stable")][:MAX_RADAR_TARGETS]
        targets[: len(chosen)] = np.stack([boxes[chosen, 0], boxes[chosen, 1], speed[chosen]], axis=1)
        valid[: len(chosen)] = True
    return {"radar_targets": targets, "radar_targets_valid": valid}


def reference_trajectory(future: np.ndarray, times: tuple[float, ...]) -> dict[str, np.ndarray]:
    knots = np.vstack([np.zeros((1, 4), np.float32), future])
    poses, valid = resample(knots[:, 0], knots[:, 1:], np.asarray(times), angle_columns=(2,))
    out = {"waypoints": np.nan_to_num(poses[:, :2]).astype(np.float32), "waypoints_valid": valid}
    heading_valid = valid & np.isfinite(poses[:, 2])
    if heading_valid.any():
        out["headings"] = np.nan_to_num(poses[:, 2]).astype(np.float32)
        out["headings_valid"] = heading_valid
    return out


def reference_lead_route(route: np.ndarray, count: int) -> dict[str, np.ndarray]:
    """LEAD's pursuit on numpy 2-vectors (the code before the Python-float loop): ``np.unique`` rows, numpy's
    ``hypot`` and dot."""
    route = np.asarray(route, np.float64)[:, :2]
    _, first = np.unique(route, axis=0, return_index=True)
    route = route[np.sort(first)]
    points, invalid = (
        np.zeros((count, 2)),
        {"route": np.zeros((count, 2), np.float32), "route_valid": np.zeros(count, bool)},
    )
    if len(route) < min(2, count):
        return invalid
    last, previous = np.zeros(2), np.zeros(2)
    for i in range(count):
        radius = 2.5 if i == 0 else 1.0
        if i < len(route):
            line = route[i] - last
            length = float(np.hypot(*line))
            if length == 0.0:
                return invalid
            unit = line / length
            point = last + radius * unit if float(unit @ (route[i] - previous)) > 0 else last - radius * unit
            previous = route[i]
        else:
            direction, offset = route[-1] - route[-2], route[-2] - last
            a, b = float(direction @ direction), 2 * float(direction @ offset)
            discriminant = b * b - 4 * a * (float(offset @ offset) - radius**2)
            if a == 0.0 or discriminant < 0:
                return invalid
            point = route[-2] + (-b + np.sqrt(discriminant)) / (2 * a) * direction
        points[i] = last = point
    if not np.isfinite(points).all():
        return invalid
    return {"route": points.astype(np.float32), "route_valid": np.ones(count, bool)}


def assert_bit_identical(got: dict[str, torch.Tensor], expected: dict[str, np.ndarray]) -> None:
    """Same names, dtypes, shapes and bits (a NaN equals a NaN, -0.0 differs from 0.0), contiguous tensors."""
    assert set(got) == set(expected)
    for name, value in expected.items():
        tensor = got[name]
        assert tensor.is_contiguous(), name
        assert tensor.dtype == torch.from_numpy(value).dtype and tuple(tensor.shape) == value.shape, name
        bits = tensor.numpy().reshape(-1).view(np.uint8)
        np.testing.assert_array_equal(bits, value.reshape(-1).view(np.uint8), err_msg=name)


# --------------------------------------------------------------------------- radar


def random_radar(rng: np.random.Generator, boxes: np.ndarray, n: int) -> np.ndarray:
    """Radar points, about half scattered around the boxes (hits and near misses), the rest anywhere."""
    radar = np.zeros((n, 5), np.float32)
    radar[:, :2] = rng.uniform([-40, -45], [70, 45], (n, 2))
    if len(boxes):
        near = rng.random(n) < 0.5
        around = boxes[rng.integers(0, len(boxes), near.sum()), :2]
        radar[near, :2] = around + rng.normal(0, 3, (near.sum(), 2))
    radar[:, 2:] = rng.normal(0, 3, (n, 3))
    return radar


@pytest.mark.parametrize(("boxes", "points"), [(0, 10), (6, 0), (1, 1), (65, 300), (200, 300)])
def test_radar_targets_equal_the_rotated_footprint_definition(boxes: int, points: int) -> None:
    rng = np.random.default_rng(boxes * 1000 + points)
    box_array = random_boxes(rng, boxes)
    radar = random_radar(rng, box_array, points)
    if points > 10:
        radar[:3, 0] = [np.nan, np.inf, -np.inf]  # never a hit
    expected = reference_radar_targets(radar, box_array)
    assert_bit_identical(radar_targets(radar, box_array), expected)
    assert_bit_identical(
        radar_targets(radar.astype(np.float64), box_array), reference_radar_targets(radar.astype(np.float64), box_array)
    )
    if boxes == 200:
        assert expected["radar_targets_valid"].all()  # the 20-target cap binds


def test_radar_points_on_the_grown_footprint_edge_hit_and_one_ulp_beyond_miss() -> None:
    boxes = np.zeros((4, 10), np.float32)
    boxes[:, :2] = [[10.0, 5.0], [30.0, 5.0], [50.0, 5.0], [70.0, 5.0]]
    boxes[:, 3:5] = [4.0, 2.0]  # grown by 0.5 m: half extents 2.5 and 1.5, exact in float32
    boxes[:, 7] = [1.0, 2.0, 3.0, 4.0]  # speeds, so the order of the targets is known
    beyond = np.nextafter(np.float32(52.5), np.float32(np.inf))
    radar = np.zeros((4, 5), np.float32)
    radar[:, :2] = [[12.5, 5.0], [27.5, 6.5], [beyond, 5.0], [70.0, np.nextafter(np.float32(3.5), np.float32(0))]]
    out = radar_targets(radar, boxes)
    assert out["radar_targets_valid"].tolist()[:3] == [True, True, False]
    assert out["radar_targets"][:2].tolist() == [[30.0, 5.0, 2.0], [10.0, 5.0, 1.0]]  # edge and corner hit
    assert_bit_identical(out, reference_radar_targets(radar, boxes))


def test_radar_priority_ranks_every_lead_class_by_leads_order_and_the_rest_last() -> None:
    classes = np.array([*LeadBoxClass, -1, len(LeadBoxClass), 99, LeadBoxClass.PARKING, LeadBoxClass.SPECIAL])
    last = len(RADAR_PRIORITY)
    expected = [RADAR_PRIORITY.index(c) if c in RADAR_PRIORITY else last for c in classes.tolist()]
    got = radar_priority(classes)
    assert got.dtype == np.int64 and got.tolist() == expected
    assert radar_priority(np.zeros(0, np.int64)).shape == (0,)


# --------------------------------------------------------------------------- LiDAR


def edge_points(grid: BEVGrid) -> np.ndarray:
    """Points on every cell edge along x and y (both grid borders included), and NaN, inf and overflowing ones."""
    h, w = grid.shape
    xs = grid.x_min + np.arange(h + 1) / grid.pixels_per_meter  # x_max itself is off the grid
    ys = grid.y_min + np.arange(w + 1) / grid.pixels_per_meter
    on_edges = np.concatenate([np.stack([xs, np.full_like(xs, 1.0)], 1), np.stack([np.full_like(ys, 1.0), ys], 1)])
    odd = [[np.nan, 0], [0, np.nan], [np.inf, 0], [0, -np.inf], [3e38, 0], [0, -3e38], [-0.0, -0.0]]
    points = np.zeros((len(on_edges) + len(odd), 4))
    points[:, :2] = np.concatenate([on_edges, odd])
    return points


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("grid", [CARLA_BEV, BEVGrid(-8, 8, -6, 6, 8.0)])
def test_lidar_points_on_cell_edges_and_off_the_grid_equal_the_histogram(dtype: type, grid: BEVGrid) -> None:
    points = edge_points(grid).astype(dtype)
    got = rasterize_lidar(points, grid)
    np.testing.assert_array_equal(
        lidar_input(torch.from_numpy(got), torch.float32).numpy(), reference_lidar(points, grid)
    )
    h, w = grid.shape
    row_one = round((1.0 - grid.x_min) * grid.pixels_per_meter)
    col_one = round((1.0 - grid.y_min) * grid.pixels_per_meter)
    assert got[:, col_one].sum() == h + 1 and got[row_one, :].sum() == w + 1  # x_max, y_max dropped; (1, 1) twice
    assert got[0, col_one] == got[h - 1, col_one] == 1  # the lower border lands in row 0, the last edge in row h-1


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lidar_points_just_below_cell_edges_and_past_mid_cell_equal_the_histogram(dtype: type) -> None:
    edges = edge_points(CARLA_BEV).astype(dtype)
    below, past_mid = edges.copy(), edges.copy()
    below[:, :2] = np.nextafter(edges[:, :2], dtype(-np.inf))  # the previous cell, unless the scaling rounds up
    past_mid[:, :2] += dtype(0.6 / CARLA_BEV.pixels_per_meter)  # truncation, not rounding, picks the cell
    for points in (below, past_mid):
        got = lidar_input(torch.from_numpy(rasterize_lidar(points, CARLA_BEV)), torch.float32)
        np.testing.assert_array_equal(got.numpy(), reference_lidar(points, CARLA_BEV))


def test_lidar_cells_past_float32s_exact_integers_count_and_half_floats_are_refused() -> None:
    grid = BEVGrid(0.0, 4097.0, 0.0, 4096.0, 1.0)  # 4097 * 4096 > 2**24: a float32 cell index would round
    points = np.array([[4096.5, 4095.5, 0, 0], [4096.5, 4094.5, 0, 0], [4096.5, 4095.5, 0, 0]], np.float32)
    raster = rasterize_lidar(points, grid)
    assert raster[4096, 4095] == 2 and raster[4096, 4094] == 1 and raster.sum() == 3
    with pytest.raises(TypeError, match=r"'lidar'.*float16"):  # 11 bits of mantissa: cell 2049 would round
        rasterize_lidar(np.zeros((1, 4), np.float16), CARLA_BEV)


# --------------------------------------------------------------------------- route and trajectory


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def future(steps: int, headings: bool = True) -> np.ndarray:
    """(t, x, y, heading) at 20 Hz along a curve whose heading passes through +-pi (unwrapped by resample)."""
    t = np.arange(1, steps + 1) / 20.0
    heading = 2.8 + 0.3 * t if headings else np.full_like(t, np.nan)
    return np.stack([t, 6.0 * t, 0.4 * t**2, heading], 1).astype(np.float32)


@pytest.mark.parametrize("knots", [future(60), future(7), future(60, headings=False), future(0)])
@pytest.mark.parametrize("source", ["carla", "navsim", "wod"])
def test_trajectory_equals_the_nan_to_num_definition(knots: np.ndarray, source: str) -> None:
    transform = SourceTransform(source, sensor_spec(), [])
    expected = reference_trajectory(knots, transform.spec.trajectory_grids[source].times)
    assert_bit_identical(transform.trajectory(knots), expected)


def random_routes(rng: np.random.Generator) -> list[np.ndarray]:
    """Routes that reach every path of the pursuit: repeated rows (adjacent or not, -0.0 beside 0.0), routes shorter
    than the targets (continued on their last line) down to a single point, points on the ego, chords that turn
    back, grid-like values whose steps are perpendicular to the chord (dot products of 0), NaN and inf points."""
    routes = []
    for _ in range(400):
        k = int(rng.integers(0, 16))
        route = np.cumsum(rng.normal(0.0, rng.choice([0.3, 1.0, 4.0]), (k, 2)), axis=0) + rng.normal(2.0, 3.0, 2)
        if rng.random() < 0.3:
            route = np.round(route * 2) / 2  # a half-metre lattice: exact steps, perpendicular ones among them
        if k and rng.random() < 0.1:
            route[rng.integers(0, k)] = (-0.0, 0.0) if rng.random() < 0.5 else (0.0, -0.0)
        if k and rng.random() < 0.1:
            route[rng.integers(0, k), int(rng.integers(0, 2))] = rng.choice([np.nan, np.inf, -np.inf])
        if k and rng.random() < 0.4:
            route = route[rng.integers(0, k, k + 3)]  # repeats (NaN rows too), in and out of order
        routes.append(route.astype(rng.choice([np.float32, np.float64])))
    return [*routes, np.array([[0.0, 0.0], [-0.0, 0.0], [0.0, -0.0], [3.0, 0.0]]), np.array([[0.0, 1.0], [1.0, 1.0]])]


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("count", [0, 1, 3, 10, 20])
def test_lead_route_equals_the_numpy_pursuit(count: int) -> None:
    for route in random_routes(np.random.default_rng(count)):
        assert_bit_identical(lead_route(route, count), reference_lead_route(route, count))


def test_dot_sign_near_zero_is_numpys() -> None:
    """Nearly perpendicular unit vectors and steps: where the plain sum of the products could round to the other
    side of 0 than numpy's dot, the sign is numpy's."""
    rng = np.random.default_rng(5)
    for ax, ay, scale in zip(
        rng.normal(size=2000), rng.normal(size=2000), 10.0 ** rng.uniform(-8, 3, 2000), strict=True
    ):
        bx, by = -ay * scale * (1 + rng.normal() * 1e-15), ax * scale
        assert np.sign(_dot_sign(ax, ay, bx, by)) == np.sign(np.array([ax, ay]) @ np.array([bx, by]))


# --------------------------------------------------------------------------- ego scalars


@pytest.mark.parametrize(("speed", "acceleration", "command"), [(6.1, [0.3, -0.0], 4), (0, [1, 2], 1)])
def test_ego_scalars_equal_torch_tensor_of_the_meta(speed: float, acceleration: list, command: int) -> None:
    meta = {
        "dataset": "carla_lead",
        "ego": {"speed": speed, "acceleration": acceleration, "command": command},
        "extras": {"carla_lead": {"target_speed": 8.3}},
    }
    out = SourceTransform("carla", sensor_spec(), [])({"__key__": "k", "meta": meta})
    expected = {
        "speed": torch.tensor(float(speed)),
        "acceleration": torch.tensor(acceleration, dtype=torch.float32),
        "command": torch.tensor(int(command4(command)), dtype=torch.int64),
        "target_speed": torch.tensor(8.3),
        "target_speed_valid": torch.tensor(True),
    }
    assert_bit_identical({name: out[name] for name in expected}, {k: v.numpy() for k, v in expected.items()})
