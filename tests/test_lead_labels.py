"""LEAD's label spaces and box encoding built from our samples (lead_s2r.data.lead_labels, lead_centernet) and LEAD's
box maps read back in our frame (lead_s2r.models.lead_frame.boxes_from_lead)."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from lead_s2r.data.lead_centernet import (
    CENTERNET_STRIDE,
    angle_bin,
    gaussian_kernel,
    gaussian_radius,
    kernel_radius,
    lead_centernet_targets,
)
from lead_s2r.data.lead_labels import (
    LeadBevClass,
    LeadBoxClass,
    bev_labels,
    lead_bev_labels,
    lead_box_classes,
    traffic_light_classes,
)
from lead_s2r.data.lead_origin import to_centre_origin
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.config import NAVSIM_BEV, BEVGrid
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.inputs import IGNORE_CLASS
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_frame import BOX_FIELDS, boxes_from_lead
from lead_s2r.schema import BevClassCarla, BoxClass

TINY = Path(__file__).parent / "data" / "lead_tfv6" / "tiny_ltfv6_navsim"


def _box(x: float, y: float, length: float, width: float, yaw: float, cls: int, speed: float = 0.0) -> list[float]:
    return [x, y, 0.0, length, width, 1.5, yaw, speed, 0.0, float(cls)]


def _cell(grid: BEVGrid, x: float, y: float, stride: int = 4) -> tuple[int, int]:
    cell = stride / grid.pixels_per_meter
    return math.floor((x - grid.x_min) / cell), math.floor((y - grid.y_min) / cell)


def test_converted_carla_boxes_land_in_leads_box_and_bev_classes(carla_samples) -> None:
    """The generated route's first frame: vehicle, emergency vehicle and pedestrian each peak in LEAD's channel for
    it (leaderboard mode, LEAD's frame: origin at the vehicle centre); the plain traffic cone and the green light
    are not LEAD detections; the BEV label holds LEAD's road and occupancy classes."""
    from lead_reference import TINY_CARLA

    config = LeadConfig.from_json({**TINY_CARLA, "use_bev_semantic": True})
    spec = input_spec(config)
    sample = to_centre_origin(carla_samples[0])
    out = SourceTransform("carla", spec)(carla_samples[0])
    expected = {
        BoxClass.VEHICLE: LeadBoxClass.VEHICLE,
        BoxClass.EMERGENCY_VEHICLE: LeadBoxClass.SPECIAL,
        BoxClass.PEDESTRIAN: LeadBoxClass.WALKER,
    }
    heatmap = out["lead_box_heatmap"]
    assert heatmap.shape == (8, 48, 40)
    classes = {int(BoxClass(int(box[9]))) for box in sample["boxes"]}
    assert classes == {*expected, BoxClass.TRAFFIC_CONE, BoxClass.TRAFFIC_LIGHT}
    assert heatmap[LeadBoxClass.OBSTACLE].max() == 0 and heatmap[LeadBoxClass.TRAFFIC_LIGHT].max() == 0
    for box in sample["boxes"][np.isin(sample["boxes"][:, 9], list(expected))]:
        row, col = _cell(spec.bev, box[0], box[1])
        lead = expected[BoxClass(int(box[9]))]
        assert heatmap[lead, row, col] == 1.0 and out["lead_box_weight"][row, col]
        assert [int(c) for c in torch.nonzero(heatmap[:, row, col] == 1.0)] == [lead]
    vehicle = sample["boxes"][sample["boxes"][:, 9] == BoxClass.VEHICLE][0]
    row, col = _cell(spec.bev, vehicle[0], vehicle[1])
    assert out["lead_box_size"][:, row, col].tolist() == pytest.approx([4.9 / 4, 2.12 / 4])  # half extents, 2 m cells
    assert out["lead_box_velocity"][row, col] == pytest.approx(math.hypot(vehicle[7], vehicle[8]))
    bev = out["bev_semantic"].numpy()
    stored = bev_labels(sample["bev_semantic"], sample["meta"]["bev"], spec.bev)
    assert bev[_cell(spec.bev, vehicle[0], vehicle[1], stride=1)] == LeadBevClass.VEHICLE
    emergency = sample["boxes"][sample["boxes"][:, 9] == BoxClass.EMERGENCY_VEHICLE][0]
    assert bev[_cell(spec.bev, emergency[0], emergency[1], stride=1)] == LeadBevClass.SPECIAL_VEHICLE
    road = stored == BevClassCarla.ROAD
    assert road.sum() > 100 and set(np.unique(bev[road])) <= {LeadBevClass.ROAD, *range(4, 11)}  # 10: the light
    assert (bev[road] == LeadBevClass.ROAD).mean() > 0.9
    assert set(np.unique(bev)) <= set(range(13))


@pytest.mark.parametrize("leaderboard", [True, False])
def test_hdmap_classes_become_leads_bev_classes(leaderboard: bool) -> None:
    """LEAD's ChauffeurNet -> TransFuser BEV table, and in sim-to-real its stop-sign area unlabelled."""
    grid = BEVGrid(0.0, 1.0, 0.0, 3.0, 4.0)
    hdmap = np.array([[*range(9), IGNORE_CLASS, 0, 0]] * 4, np.uint8)
    labels = lead_bev_labels(hdmap, np.zeros((0, 10)), grid, leaderboard, np.zeros(0, np.int64))
    stop = LeadBevClass.STOP_SIGNS if leaderboard else LeadBevClass.UNLABELED
    assert labels[0].tolist() == [0, 1, 0, 2, 2, stop, 0, 0, 0, IGNORE_CLASS, 0, 0]


def test_box_footprints_are_drawn_over_the_map_as_lead_draws_them() -> None:
    """A 4 x 2 m vehicle fills 17 x 9 pixels (LEAD's corners truncated, edges filled); a pedestrian is drawn 2.5 x
    its half extent of at least 0.4 m (2 m square); in sim-to-real an emergency vehicle is a vehicle and a
    construction cone is not drawn."""
    road = np.full(NAVSIM_BEV.shape, BevClassCarla.ROAD, np.uint8)
    boxes = np.array(
        [
            _box(10.0, 5.0, 4.0, 2.0, 0.0, BoxClass.VEHICLE),
            _box(-10.0, -10.0, 0.5, 0.3, 0.7, BoxClass.PEDESTRIAN),
            _box(20.0, -20.0, 6.0, 2.5, 0.0, BoxClass.EMERGENCY_VEHICLE),
            _box(0.0, 20.0, 0.4, 0.4, 0.0, BoxClass.CZONE_SIGN),
        ],
        np.float32,
    )
    not_lights = np.full(len(boxes), -1)
    for leaderboard in (True, False):
        labels = lead_bev_labels(road, boxes, NAVSIM_BEV, leaderboard, not_lights)
        rows, cols = np.nonzero(labels == LeadBevClass.VEHICLE)
        if leaderboard:
            assert (rows.min(), rows.max(), cols.min(), cols.max(), len(rows)) == (160, 176, 143, 151, 153)
            assert (labels == LeadBevClass.SPECIAL_VEHICLE).sum() == 25 * 11
            assert (labels == LeadBevClass.OBSTACLE).sum() > 0
        else:
            assert len(rows) == 153 + 25 * 11 and (labels >= LeadBevClass.OBSTACLE).sum() == 0
        walker = labels == LeadBevClass.WALKER
        assert 64 <= walker.sum() <= 90  # a 2 m square rotated by 0.7 rad: 64 pixels and the filled edges
        assert walker[_cell(NAVSIM_BEV, -10.0, -10.0, stride=1)]
    assert (lead_bev_labels(road, boxes[:0], NAVSIM_BEV, True, not_lights[:0]) == LeadBevClass.ROAD).all()


def test_our_box_classes_become_leads() -> None:
    """Plain traffic cones are no LEAD obstacle (only construction cones and warnings, our CZONE_SIGN); a traffic
    light is detected only when it affects the ego and is red or yellow."""
    ours = np.array([int(c) for c in BoxClass])
    red = traffic_light_classes(ours, {"traffic_light_states": ["Red"], "traffic_light_affects_ego": [True]})
    assert red.tolist() == [-1] * 7 + [LeadBevClass.TRAFFIC_RED_NORMAL, -1, -1]
    assert lead_box_classes(ours, True, red).tolist() == [0, 1, 7, -1, -1, 5, -1, 2, 3, 4]
    assert lead_box_classes(ours, False, red).tolist() == [0, 1, 7, -1, -1, 5, -1, 2, 3, 0]
    for state, affects in (("Green", True), ("Red", False)):
        light = traffic_light_classes(ours, {"traffic_light_states": [state], "traffic_light_affects_ego": [affects]})
        assert lead_box_classes(ours, True, light)[BoxClass.TRAFFIC_LIGHT] == -1
    assert lead_box_classes(np.array([-1, 99]), True, np.array([-1, -1])).tolist() == [-1, -1]


def test_leads_encoding_of_one_box_by_hand() -> None:
    """A 4 x 2 m box at (5.3, -3.7), yaw 0.3, on NAVSIM's 1 m CenterNet cells: cell (37, 28), offset 0.3, half
    extents (2, 1), radius max(2, 0.41) = 2 with sigma 5/6, yaw bin 1 with residual 0.3 - pi/6."""
    assert gaussian_radius(1.0, 2.0) == pytest.approx(0.414590, abs=1e-6)
    targets = lead_centernet_targets(
        np.array([_box(5.3, -3.7, 4.0, 2.0, 0.3, BoxClass.VEHICLE, 7.0)]), np.array([0]), NAVSIM_BEV, 1, 12
    )
    heat = targets["lead_box_heatmap"][0]
    assert heat[37, 28] == 1.0 and heat[36, 28] == pytest.approx(math.exp(-0.72)) and heat[35, 26] > 0
    assert heat[34, 28] == 0.0 and int((heat[:, :-3] > 0).sum()) == 25  # columns left of LEAD's padding box
    assert targets["lead_box_size"][:, 37, 28].tolist() == [2.0, 1.0]
    assert targets["lead_box_offset"][:, 37, 28].tolist() == pytest.approx([0.3, 0.3], abs=1e-5)
    assert int(targets["lead_box_yaw_class"][37, 28]) == 1
    assert float(targets["lead_box_yaw_residual"][37, 28]) == pytest.approx(0.3 - math.pi / 6, abs=1e-6)
    assert float(targets["lead_box_velocity"][37, 28]) == 7.0
    # LEAD's padding box: class 0, size 0 at LEAD's corner cell (our row 0, last column), counted as a peak
    assert float(targets["lead_box_count"]) == 2.0 and int(targets["lead_box_weight"].sum()) == 2
    assert heat[0, -1] == 1.0 and targets["lead_box_offset"][:, 0, -1].tolist() == [0.0, 1.0]
    assert angle_bin(-0.3, 12) == (11, pytest.approx(math.pi / 6 - 0.3))
    assert angle_bin(math.pi, 12) == (6, pytest.approx(0.0, abs=1e-12))
    kernel = gaussian_kernel(3)
    assert kernel.shape == (7, 7) and kernel[3, 3] == 1.0
    assert kernel[0, 0] == pytest.approx(math.exp(-18 / (2 * (7 / 6) ** 2)))


def _paste_max(heatmap: np.ndarray, row: int, col: int, window: np.ndarray) -> None:
    """``heatmap = max(heatmap, window)`` with the (2r+1)^2 ``window`` centred on (row, col), cut at the edges."""
    radius = window.shape[0] // 2
    for i in range(window.shape[0]):
        for j in range(window.shape[1]):
            r, c = row + i - radius, col + j - radius
            if 0 <= r < heatmap.shape[0] and 0 <= c < heatmap.shape[1]:
                heatmap[r, c] = max(heatmap[r, c], window[i, j])


def _centernet_box_by_box(boxes: np.ndarray, classes: np.ndarray, grid: BEVGrid) -> dict[str, np.ndarray]:
    """LEAD's per-box loop, written plainly: each box's Gaussian pasted, then its cell's values overwritten; then LEAD's
    padding box."""
    cell = CENTERNET_STRIDE / grid.pixels_per_meter
    h, w = grid.shape[0] // CENTERNET_STRIDE, grid.shape[1] // CENTERNET_STRIDE
    heat, size, offset = (
        np.zeros((3, h, w), np.float32),
        np.zeros((2, h, w), np.float32),
        np.zeros((2, h, w), np.float32),
    )
    yaw_class, yaw_residual = np.zeros((h, w), np.uint8), np.zeros((h, w), np.float32)
    speed, weight = np.zeros((h, w), np.float32), np.zeros((h, w), bool)
    for box, label in zip(boxes.tolist(), classes.tolist(), strict=True):
        x, y = (box[0] - grid.x_min) / cell, (box[1] - grid.y_min) / cell
        if label < 0 or not (0 <= x < h and 0 < y <= w):
            continue
        row, col = math.floor(x), math.ceil(y) - 1
        _paste_max(
            heat[label], row, col, gaussian_kernel(max(2, int(gaussian_radius(box[4] / 2 / cell, box[3] / 2 / cell))))
        )
        size[:, row, col] = box[3] / 2 / cell, box[4] / 2 / cell
        offset[:, row, col] = x - row, y - col
        yaw_bin, residual = angle_bin(np.array([box[6]]), 12)
        yaw_class[row, col], yaw_residual[row, col] = int(yaw_bin[0]), float(residual[0])
        speed[row, col], weight[row, col] = np.hypot(box[7], box[8]), True
    _paste_max(heat[0], 0, w - 1, gaussian_kernel(2))  # LEAD's padding box (fewer than 90 boxes), written last
    size[:, 0, w - 1], offset[:, 0, w - 1], yaw_class[0, w - 1] = 0.0, (0.0, 1.0), 0
    yaw_residual[0, w - 1], speed[0, w - 1], weight[0, w - 1] = 0.0, 0.0, True
    count = np.float32(max(1, int((heat == 1).sum())))
    names = ("heatmap", "size", "offset", "yaw_class", "yaw_residual", "velocity", "weight", "count")
    maps = (heat, size, offset, yaw_class, yaw_residual, speed, weight, count)
    return {f"lead_box_{name}": value for name, value in zip(names, maps, strict=True)}


def test_centernet_targets_equal_the_box_by_box_loop_bit_for_bit() -> None:
    """Boxes encoded in one compiled pass equal LEAD's per-box loop, every map byte for byte, with many boxes sharing
    cells (the last one's values win), centres on cell edges and off the grid, kernels cut at every edge (large
    boxes, up to 90 m), and speeds unknown (NaN)."""
    rng = np.random.default_rng(7)
    grid = BEVGrid()
    for trial in range(40):
        n = int(rng.integers(1, 80))
        boxes = np.zeros((n, 10))
        boxes[:, 0], boxes[:, 1] = rng.uniform(-35, 67, n), rng.uniform(-43, 43, n)
        if trial % 2:
            boxes[:, :2] = np.round(boxes[:, :2])  # on cell edges, and many boxes in one cell
        boxes[:, 3], boxes[:, 4], boxes[:, 6] = rng.uniform(0.1, 12, n), rng.uniform(0.1, 4, n), rng.uniform(-7, 7, n)
        boxes[:, 7:9] = rng.normal(0, 5, (n, 2))
        if trial % 3 == 0:
            boxes[:3, 3:5] = rng.uniform(10, 90, (min(n, 3), 2))  # radii past 8 cells: the kernel bank grows
            boxes[rng.random(n) < 0.2, 7:9] = np.nan
        classes = rng.integers(-1, 3, n)
        ours = lead_centernet_targets(boxes, classes, grid, 3, 12)
        reference = _centernet_box_by_box(boxes, classes, grid)
        assert set(ours) == set(reference)
        for key, expected in reference.items():
            assert ours[key].numpy().tobytes() == expected.tobytes(), (trial, key)
    assert kernel_radius(1.0, 2.0) == 2 and kernel_radius(6.0, 20.0) == int(gaussian_radius(6.0, 20.0))


def test_boxes_off_the_grid_or_of_no_class_are_not_encoded() -> None:
    boxes = np.array([_box(40.0, 0.0, 4, 2, 0, 0), _box(0.0, 0.0, 4, 2, 0, 6), _box(1.0, 1.0, 4, 2, 0, 0)])
    targets = lead_centernet_targets(boxes, np.array([0, -1, 0]), NAVSIM_BEV, 1, 12, velocity=False)
    # y = 1 m lies on a cell edge: LEAD's truncation of its y right puts it in our column 32; + LEAD's padding box
    assert int(targets["lead_box_weight"].sum()) == 2 and bool(targets["lead_box_weight"][33, 32])
    assert "lead_box_velocity" not in targets
    empty = lead_centernet_targets(np.zeros((0, 10)), np.zeros(0), NAVSIM_BEV, 1, 12)
    assert float(empty["lead_box_count"]) == 1.0 and not empty["lead_box_heatmap"][:, 3:, :-3].any()


def _decode(maps: dict[str, torch.Tensor], row: int, col: int, b: int) -> tuple[float, ...]:
    """(x, y, half length, half width, yaw) in cells at one cell of maps in our box names."""
    yaw_class = int(maps["box_yaw_class"][b, :, row, col].argmax())
    yaw = yaw_class * 2 * math.pi / maps["box_yaw_class"].shape[1] + float(maps["box_yaw_residual"][b, 0, row, col])
    offset, size = maps["box_offset"][b, :, row, col], maps["box_size"][b, :, row, col]
    return row + float(offset[0]), col + float(offset[1]), float(size[0]), float(size[1]), yaw


def test_leads_decoded_boxes_read_in_our_frame_are_its_boxes_mirrored() -> None:
    """LEAD's own decoding of the tiny LTFv6's box maps (postprocess.pt: grid cells x pixels_per_meter, y right) equals
    ours read at the same cells after boxes_from_lead: same x and size, y mirrored across the grid, yaw negated.

    Each decoded box's cell is found in LEAD's layout (row = its y cell, column = its x cell) as the cell whose
    offset lands on the decoded centre; our cell is that one moved as bev_map_from_lead moves it."""
    outputs = torch.load(TINY / "outputs.pt", weights_only=True)
    decoded = torch.load(TINY / "postprocess.pt", weights_only=True)
    decoded = decoded["pred_bounding_box_navsim.pred_bounding_box_image_system"]
    prefix = "pred_bounding_box_navsim."
    ours = boxes_from_lead({f: outputs[prefix + f] for f in BOX_FIELDS})
    lead_offset = outputs[prefix + "offset_pred"]
    size, ppm = lead_offset.shape[-1], 2.0
    cells = torch.arange(size, dtype=torch.float32)
    for b in range(2):
        centre_x = cells[None, :] + lead_offset[b, 0]  # LEAD rows: y cells, columns: x cells
        centre_y = cells[:, None] + lead_offset[b, 1]
        for box in decoded[b, :10].tolist():
            hit = ((centre_x - box[0] / ppm).abs() < 1e-5) & ((centre_y - box[1] / ppm).abs() < 1e-5)
            (lead_row, lead_col), *others = torch.nonzero(hit).tolist()
            assert not others
            x, y, half_length, half_width, yaw = _decode(ours, lead_col, size - 1 - lead_row, b)
            assert x == pytest.approx(box[0] / ppm, abs=1e-5) and y == pytest.approx(size - box[1] / ppm, abs=1e-5)
            assert (half_length, half_width) == pytest.approx((box[2] / ppm, box[3] / ppm), abs=1e-6)
            assert math.remainder(yaw + box[4], 2 * math.pi) == pytest.approx(0.0, abs=1e-5)


def test_leads_box_loss_by_hand_and_a_sample_without_boxes_adds_nothing() -> None:
    """Zero maps (probability 1/2 everywhere, all bins equal) against one encoded box and LEAD's padding box (size 0,
    offset (0, 1) in our frame, yaw 0, speed 0): focal sum + L1 of size (2 + 1) and offset (0.3 + 0.3 + 1) per
    channel + ln 12 per box + smooth L1 of the residual + speed 7, over two peaks; a second sample carrying the
    collate filler (heatmap -1) is left out of the mean."""
    from lead_s2r.data.collate import collate
    from lead_s2r.training.losses import lead_box_loss

    box = np.array([_box(5.3, -3.7, 4.0, 2.0, 0.3, BoxClass.VEHICLE, 7.0)])
    one = lead_centernet_targets(box, np.array([0]), NAVSIM_BEV, 1, 12)
    batch = collate([one, {k: v for k, v in one.items() if k != "lead_box_heatmap"}])
    assert batch["lead_box_heatmap"][1].eq(-1).all()
    pred = {name: torch.zeros(2, channels, 64, 64) for name, channels in
            [("box_heatmap", 1), ("box_size", 2), ("box_offset", 2), ("box_yaw_class", 12), ("box_yaw_residual", 1),
             ("box_velocity", 1)]}  # fmt: skip
    heat = one["lead_box_heatmap"].double()
    focal = (math.log(2) / 4 * ((heat == 1) + (1 - heat).pow(4) * (heat < 1))).sum()
    residual = 0.3 - math.pi / 6
    expected = (float(focal) + 1.5 + 0.8 + 2 * math.log(12) + 0.5 * residual**2 + 7.0) / 2
    assert float(lead_box_loss(pred, batch, velocity=True)) == pytest.approx(expected, rel=1e-5)
    assert float(lead_box_loss(pred, batch, velocity=False)) == pytest.approx(expected - 3.5, rel=1e-5)


def test_carla_bev_labels_of_another_class_table_are_refused(carla_samples) -> None:
    from lead_reference import TINY_CARLA

    from lead_s2r.errors import UserError

    spec = input_spec(LeadConfig.from_json({**TINY_CARLA, "use_bev_semantic": True}))
    sample = carla_samples[0]
    meta = {**sample["meta"], "bev": {**sample["meta"]["bev"], "classes": "navsim"}}
    with pytest.raises(UserError, match=r"field 'meta.bev.classes'.*'navsim'"):
        SourceTransform("carla", spec)({**sample, "meta": meta})


def test_our_targets_are_leads_targets_of_the_mirrored_boxes_read_through_boxes_from_lead() -> None:
    """LEAD's encoding written plainly in its frame (y right, rows along y, columns along x) for random boxes, put
    through boxes_from_lead as if a network had predicted it exactly, gives our targets at every box cell."""
    rng = np.random.default_rng(0)
    grid, bins, n = NAVSIM_BEV, 12, 20
    boxes = np.zeros((n, 10))
    boxes[:, :2] = rng.uniform(-31.5, 31.5, (n, 2))
    boxes[:, 3:5] = rng.uniform(1, 6, (n, 2))
    boxes[:, 6] = rng.uniform(-math.pi, math.pi, n)
    ours = lead_centernet_targets(boxes, np.zeros(n), grid, 1, bins, velocity=False)
    size = 64
    lead = {name: torch.zeros(1, channels, size, size) for name, channels in
            [("wh_pred", 2), ("offset_pred", 2), ("yaw_class_pred", bins), ("yaw_res_pred", 1)]}  # fmt: skip
    for x, y, length, width, yaw in boxes[:, [0, 1, 3, 4, 6]]:
        ctx, cty = x - grid.x_min, -y - grid.y_min  # LEAD: 1 m cells, y to the right
        row, col = int(cty), int(ctx)
        angle = yaw * -1 % (2 * math.pi)
        k = int(((angle + math.pi / bins) % (2 * math.pi)) // (2 * math.pi / bins))
        lead["wh_pred"][0, :, row, col] = torch.tensor([length / 2, width / 2])
        lead["offset_pred"][0, :, row, col] = torch.tensor([ctx - col, cty - row])
        lead["yaw_class_pred"][0, :, row, col] = 0.0
        lead["yaw_class_pred"][0, k, row, col] = 10.0
        lead["yaw_res_pred"][0, 0, row, col] = (
            (angle + math.pi / bins) % (2 * math.pi) - k * 2 * math.pi / bins - math.pi / bins
        )
    lead["yaw_class_pred"][0, 0, 0, 0] = 10.0  # LEAD's padding box at its cell (0, 0): size, offset, residual 0
    read = boxes_from_lead(lead)
    cells = ours["lead_box_weight"]
    assert int(cells.sum()) == n + 1
    assert torch.allclose(read["box_size"][0][:, cells], ours["lead_box_size"][:, cells])
    assert torch.allclose(read["box_offset"][0][:, cells], ours["lead_box_offset"][:, cells], atol=1e-5)
    assert torch.equal(read["box_yaw_class"][0].argmax(0)[cells], ours["lead_box_yaw_class"][cells].long())
    assert torch.allclose(read["box_yaw_residual"][0, 0][cells], ours["lead_box_yaw_residual"][cells], atol=1e-5)
