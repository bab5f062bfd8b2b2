"""Our CARLA data path (the carla_lead adapter, shards, :class:`~lead_s2r.data.transforms.SourceTransform`, collate)
gives a LEAD network the inputs and targets LEAD's own CARLA loader gives for the same frames.

``tests/data/lead_carla_parity/`` holds three frames of the routes ``lead-s2r synth carla_lead --count 3 --seed 0``
writes (left turn frame 6, right turn frame 3, the pedestrian stop's frame 12, standing still), each stored as the one
frame of its route folder (frame 0: our adapter reads a route's frames from the first), and what LEAD's
``CARLAData.__getitem__`` (commit 4489176, unmodified) made of them, batched by LEAD's training collate, for LEAD's
default CARLA TFv6 (leaderboard mode, 3 cameras 384 x 1152, LiDAR, radar, BEV 96 x 80 m at 4 px/m, planning decoder),
once on the normal rig and once on the perturbated rig of LEAD's recovery augmentation: its README says how it was
run. Each key is compared in LEAD's layout (y right, BEV rows along y, LEAD's one-hot command), after our batch
passes the one frame boundary (:mod:`lead_s2r.models.lead_frame`).

Integers, labels, images and rasters must be equal. Positions may differ by float rounding only (``POSITION_ATOL``):
LEAD works in float64 from the stored values, we move the origin to the rear axle in the adapter (float32 on disk)
and back to the centre in the transform. Not compared: ``source_dataset`` (ours are per-source batches),
``center_net_brake`` and ``center_net_bounding_boxes`` (no loss reads them).
"""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from lead_s2r.convert import convert
from lead_s2r.data.collate import collate
from lead_s2r.data.lead_origin import centre_waypoints_to_rear_axle
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.geometry import CARLA_REAR_AXLE_TO_CENTER, rear_axle_poses_to_centre
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.inputs import on_image_grid
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_frame import flip_y, to_lead_inputs
from lead_s2r.shards import read_samples
from lead_s2r_adapters.carla_lead import CarlaLeadAdapter

DATA = Path(__file__).parent / "data" / "lead_carla_parity"
#: The routes' scenario folders, in the order LEAD's loader was given their frames.
SCENARIOS = ["SignalizedJunctionLeftTurn", "SignalizedJunctionRightTurn", "PedestrianCrossing"]
#: LEAD's outputs per rig (``.npz`` arrays, ``.json`` shapes and the image digest).
GOLDEN = {"normal": Path("lead_loader"), "perturbated": Path("lead_loader_perturbated")}
#: LEAD's default CARLA configuration with its planner (the loader's other switches are defaults).
CONFIG = {"use_planning_decoder": True}
#: Metres: float32 rounding of positions up to ~100 m, through the rear-axle round trip (module docstring).
POSITION_ATOL = 1e-5


@pytest.fixture(scope="module", params=["normal", "perturbated"])
def rig(request: pytest.FixtureRequest) -> str:
    """The camera rig: LEAD's normal one, or its recovery augmentation's shifted and turned one (LEAD's loader with
    ``use_sensor_perburtation_prob`` 1; our adapter's ``rig="perturbated"``)."""
    return request.param


@pytest.fixture(scope="module")
def lead(rig: str) -> dict[str, np.ndarray]:
    return dict(np.load(DATA / GOLDEN[rig].with_suffix(".npz")))


@pytest.fixture(scope="module")
def ours(rig: str, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Our batch of the three frames, converted from the route folders as a user would."""
    out = tmp_path_factory.mktemp("lead_parity") / "converted"
    convert(CarlaLeadAdapter(rig=rig), DATA / "route", out)
    transform = SourceTransform("carla", input_spec(LeadConfig.from_json(CONFIG)))
    samples = {
        sample["meta"]["log_id"].split("/")[0]: transform(sample) for sample in read_samples(out, transform.fields)
    }
    assert sorted(samples) == sorted(SCENARIOS)
    return collate([samples[scenario] for scenario in SCENARIOS])


def lead_map(ours: torch.Tensor) -> np.ndarray:
    """Our (..., H = x, W = y left) BEV map in LEAD's layout (..., rows = y from left to right, columns = x)."""
    return ours.transpose(-1, -2).flip(-2).numpy()


def test_inputs_equal_leads(ours: dict, lead: dict[str, np.ndarray], rig: str) -> None:
    """The camera mosaic, LiDAR raster and radar are LEAD's bit for bit; target points, command and speed equal."""
    config = LeadConfig.from_json(CONFIG)
    inputs = to_lead_inputs(ours, config)
    rgb = json.loads((DATA / GOLDEN[rig].with_suffix(".json")).read_text())["rgb"]
    assert list(inputs["rgb"].shape) == rgb["shape"]
    pixels = np.ascontiguousarray(inputs["rgb"].numpy())
    assert hashlib.sha256(pixels.tobytes()).hexdigest() == rgb["sha256"]
    np.testing.assert_array_equal(inputs["rasterized_lidar"].numpy(), lead["rasterized_lidar"])
    assert lead["rasterized_lidar"].any()
    np.testing.assert_array_equal(inputs["radar"].numpy(), lead["radar"].astype(np.float32))
    for key in ("target_point_previous", "target_point", "target_point_next"):
        np.testing.assert_allclose(inputs[key].numpy(), lead[key], rtol=0, atol=POSITION_ATOL, err_msg=key)
    np.testing.assert_array_equal(inputs["command"].numpy(), lead["command"])  # LANE_FOLLOW is not STRAIGHT
    np.testing.assert_array_equal(inputs["speed"].numpy(), lead["speed"].astype(np.float32))


def test_planning_targets_equal_leads(ours: dict, lead: dict[str, np.ndarray]) -> None:
    """Waypoints (2 s at 4 Hz) and their yaws, the route LEAD's planner is trained on, target speed and brake."""
    assert ours["waypoints_valid"].all()
    np.testing.assert_allclose(flip_y(ours["waypoints"]).numpy(), lead["future_waypoints"], rtol=0, atol=POSITION_ATOL)
    np.testing.assert_allclose(-ours["headings"].numpy(), lead["future_yaws"], rtol=0, atol=1e-6)
    assert ours["route_valid"].all()
    np.testing.assert_allclose(flip_y(ours["route"]).numpy(), lead["route"], rtol=0, atol=POSITION_ATOL)
    np.testing.assert_array_equal(ours["target_speed"].numpy(), lead["target_speed"].astype(np.float32))
    np.testing.assert_array_equal(ours["brake"].numpy(), lead["brake"])
    assert lead["brake"].tolist() == [False, False, True]


def test_perception_targets_equal_leads(ours: dict, lead: dict[str, np.ndarray]) -> None:
    """BEV semantics, camera semantics and depth, radar detection targets."""
    np.testing.assert_array_equal(lead_map(ours["bev_semantic"]), lead["bev_semantic"])
    np.testing.assert_array_equal(ours["semantic"].numpy(), lead["semantic"])
    depth = on_image_grid(ours["depth"], tuple(lead["depth"].shape[-2:])).numpy()
    np.testing.assert_allclose(depth, lead["depth"], rtol=0, atol=1e-5)  # float32 bilinear, cv2 vs torch
    radar = lead["radar_detections"]
    valid = ours["radar_targets_valid"].numpy()
    np.testing.assert_array_equal(valid, radar[..., 3] == 1)
    np.testing.assert_allclose(flip_y(ours["radar_targets"]).numpy()[valid], radar[..., :3][valid], atol=POSITION_ATOL)


def test_centernet_targets_equal_leads(ours: dict, lead: dict[str, np.ndarray]) -> None:
    """Every CenterNet map LEAD's loss reads, cell for cell, and the per-sample normaliser."""
    weight = lead_map(ours["lead_box_weight"])
    np.testing.assert_array_equal(np.repeat(weight[:, None], 2, 1).astype(np.float32), lead["center_net_pixel_weight"])
    np.testing.assert_array_equal(lead_map(ours["lead_box_heatmap"]), lead["center_net_heatmap"])
    np.testing.assert_allclose(lead_map(ours["lead_box_size"]), lead["center_net_wh"], rtol=0, atol=1e-6)
    offset = lead_map(ours["lead_box_offset"])
    offset[:, 1] = np.where(weight, 1 - offset[:, 1], 0)  # LEAD measures the lateral fraction from the other edge
    np.testing.assert_allclose(offset, lead["center_net_offset"], rtol=0, atol=1e-5)
    bins = LeadConfig.from_json(CONFIG).num_dir_bins
    yaw_class = np.where(weight, (-lead_map(ours["lead_box_yaw_class"]).astype(np.int64)) % bins, 0)
    np.testing.assert_array_equal(yaw_class, lead["center_net_yaw_class"])  # yaw bins turn the other way
    np.testing.assert_allclose(-lead_map(ours["lead_box_yaw_residual"])[:, None], lead["center_net_yaw_res"], atol=1e-6)
    np.testing.assert_allclose(lead_map(ours["lead_box_velocity"])[:, None], lead["center_net_velocity"], atol=1e-6)
    np.testing.assert_array_equal(ours["lead_box_count"].numpy(), lead["center_net_avg_factor"])


@pytest.mark.parametrize("radius", [10.0, -10.0, 30.0])
def test_predicted_centre_waypoints_come_back_to_the_rear_axle(radius: float) -> None:
    """A LEAD CARLA network's waypoints (centre positions, centre frame) become our rear-axle positions: on a turn
    within 2 cm (the headings come from the path), on a straight and standing still exactly, and a sample that was
    never moved (origin_x 0) is unchanged."""
    t = np.arange(1, 9) * 0.25
    angle = 6.0 * t / radius
    rear = np.stack([radius * np.sin(angle), radius * (1 - np.cos(angle)), angle], axis=1)
    centre = torch.from_numpy(rear_axle_poses_to_centre(rear, CARLA_REAR_AXLE_TO_CENTER)[None, :, :2])
    back = centre_waypoints_to_rear_axle(centre, torch.tensor([CARLA_REAR_AXLE_TO_CENTER]))
    np.testing.assert_allclose(back[0].numpy(), rear[:, :2], atol=0.02)
    straight = torch.stack([torch.from_numpy(6.0 * t), torch.zeros(8, dtype=torch.float64)], -1)[None]
    both = centre_waypoints_to_rear_axle(
        torch.cat([straight, torch.zeros_like(straight)]), torch.tensor([1.389, 1.389])
    )
    torch.testing.assert_close(both, torch.cat([straight, torch.zeros_like(straight)]), rtol=0, atol=1e-12)
    assert torch.equal(centre_waypoints_to_rear_axle(centre, torch.zeros(1, dtype=torch.float64)), centre)
