"""LEAD's checkpoints in our models: parameter tables of eight LEAD configurations, output parity with a case computed
by LEAD's own code (tests/data/lead_tfv6/, copied from the golden folder), config derivation, ensembles, export."""

import io
import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from lead_reference import CASES, seeded_inputs, seeded_state

from lead_s2r.errors import UserError
from lead_s2r.models import lead
from lead_s2r.models.lead_config import LeadConfig

DATA = Path(__file__).parent / "data" / "lead_tfv6"
TINY = DATA / "tiny_ltfv6_navsim"
CONFIGS = sorted(p.name[len("config_") : -len(".json")] for p in DATA.glob("config_*.json"))
BUILDABLE = [
    name for name in CONFIGS if "fields_read_by_model" in json.loads((DATA / f"config_{name}.json").read_text())
]


def lead_table(name: str) -> tuple[dict[str, tuple[int, ...]], int]:
    """LEAD's state_dict entries (name -> shape) and parameter count of one configuration."""
    shapes, total = {}, None
    for line in (DATA / f"params_{name}.tsv").read_text().splitlines():
        cells = line.split("\t")
        if line.startswith("# total_parameters"):
            total = int(cells[1])
        elif len(cells) == 5 and not line.startswith(("#", "name\t")):
            shapes[cells[0]] = tuple(json.loads(cells[2]))
    return shapes, total


def test_all_lead_configurations_are_covered() -> None:
    assert len(BUILDABLE) == 8 and "ltfv6_wod_e2e" in CONFIGS


@pytest.mark.parametrize("name", BUILDABLE)
def test_state_dict_is_leads_entry_for_entry(name: str) -> None:
    overrides = json.loads((DATA / f"config_{name}.json").read_text())["overrides"]
    model = lead.model_from_config(overrides)
    want, total = lead_table(name)
    got = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    assert got == want
    assert sum(p.numel() for p in model.parameters()) == total


@pytest.mark.parametrize("name", BUILDABLE)
def test_derived_fields_follow_leads_rules(name: str) -> None:
    """Every field LEAD's model read (derived or not) has the value our config derives from the overrides alone."""
    spec = json.loads((DATA / f"config_{name}.json").read_text())
    ours = LeadConfig.from_json(spec["overrides"]).to_json()
    read = {k: v["value"] for k, v in spec["fields_read_by_model"].items() if k in ours}
    assert len(read) > 40
    for key, value in read.items():
        mine = ours[key]
        assert mine == pytest.approx(value) if isinstance(value, float) else mine == value, key


def test_derived_values_in_a_file_are_recomputed() -> None:
    """Derived numbers in config.json are informational for LEAD; editing one changes nothing."""
    values = json.loads((TINY / "config.json").read_text())
    edited = dict(values, lidar_width_pixel=999, img_horz_anchors=3, max_speed=1.0, use_tp=True)
    assert LeadConfig.from_json(edited) == LeadConfig.from_json(values)
    config = LeadConfig.from_json(values)
    assert (config.lidar_height_pixel, config.img_vert_anchors, config.img_horz_anchors) == (128, 8, 15)
    assert config.to_json()["target_dataset"] == values["target_dataset"]


def test_wod_configuration_builds_with_leads_rules_and_our_camera_tile() -> None:
    """LEAD's own code cannot build its WOD-E2E LTFv6; ours follows every rule LEAD's config code states for it, except
    the past-state slots its forward never fills (off) and the camera tile LEAD's missing function would give."""
    spec = json.loads((DATA / "config_ltfv6_wod_e2e.json").read_text())
    config = LeadConfig.from_json(spec["overrides"])
    known = spec["fields_known_from_config_code"]
    ours = config.to_json()
    for key in ("min_x_meter", "max_x_meter", "min_y_meter", "max_y_meter", "lidar_width_pixel", "max_speed"):
        assert ours[key] == known[key], key
    for key in ("use_acceleration", "use_discrete_command", "predict_target_speed", "predict_spatial_path"):
        assert ours[key] is known[key], key
    assert ours["target_dataset"] == 5 and ours["lidar_height_pixel"] == 256 and not config.radar_detection
    assert not (config.use_tp or config.use_previous_tp or config.use_next_tp)
    assert (config.num_way_points_prediction, config.waypoint_interval_s) == (known["num_way_points_prediction"], 0.5)
    assert (config.final_image_height, config.final_image_width) == (360, 972)
    assert not (config.use_past_positions or config.use_past_speeds)
    model = lead.model_from_config(spec["overrides"])
    assert not hasattr(model.planning_decoder, "heading_decoder")
    assert model.planning_decoder.planning_context_encoder.status_pos_embedding.shape[1] == 1  # the speed token only
    outputs = lead.forward(model, {"rgb": torch.zeros(2, 3, 360, 972), "speed": torch.tensor([3.0, 30.0])})
    assert list(outputs) == ["pred_future_waypoints"] and outputs["pred_future_waypoints"].shape == (2, 10, 2)
    with pytest.raises(UserError, match="use_past_positions"):
        LeadConfig.from_json({**spec["overrides"], "use_past_positions": True})


def test_planner_overrides_shape_the_planner() -> None:
    """Our extensions of LEAD's config: one target point, another waypoint count; LEAD's files read as before."""
    one = lead.model_from_config({**CASES["tfv6_radar"], "use_previous_tp": False, "use_next_tp": False})
    three = lead.model_from_config(CASES["tfv6_radar"])
    slots = {m: m.planning_decoder.planning_context_encoder.status_pos_embedding.shape[1] for m in (one, three)}
    assert slots[three] - slots[one] == 2
    assert one.config.target_point_slots == ("target_point",)
    twelve = lead.model_from_config({**CASES["tfv6_radar"], "num_way_points_prediction": 12})
    assert twelve.planning_decoder.query.shape[1] == three.planning_decoder.query.shape[1] + 4
    with pytest.raises(UserError, match="use_previous_tp"):
        LeadConfig.from_json({"use_navsim_data": True, "use_previous_tp": True})
    with pytest.raises(UserError, match="waypoint_interval_s"):
        LeadConfig.from_json({"waypoint_interval_s": 0})


def test_camera_tile_size_shrinks_only_the_image_input() -> None:
    """Our toy-size extension (the smoke twins' overlay): the image input and the parameters sized by its anchors
    follow the tile; every other entry keeps LEAD's shape, and without the field the tile is LEAD's."""
    small = LeadConfig.from_json({**CASES["tfv6_radar"], "camera_tile_size": [64, 32]})
    assert (small.final_image_height, small.final_image_width) == (32, 192)
    assert (small.img_vert_anchors, small.img_horz_anchors) == (1, 6)
    assert LeadConfig.from_json(small.to_json()) == small
    assert LeadConfig.from_json(CASES["tfv6_radar"]).final_image_width == 1152
    full = lead.model_from_config(CASES["tfv6_radar"]).state_dict()
    model = lead.model_from_config({**CASES["tfv6_radar"], "camera_tile_size": [64, 32]})
    changed = {k for k, v in model.state_dict().items() if v.shape != full[k].shape}
    assert model.state_dict().keys() == full.keys() and changed and all("pos_emb" in k for k in changed), changed
    inputs = seeded_inputs(CASES["tfv6_radar"])
    inputs["rgb"] = inputs["rgb"][:, :, :32, :192]
    outputs = lead.forward(model.eval(), inputs)
    assert outputs["pred_future_waypoints"].shape == (1, 8, 2)
    for bad in ([64, 48], [64], [0, 64]):
        with pytest.raises(UserError, match="camera_tile_size"):
            LeadConfig.from_json({"camera_tile_size": bad})


@pytest.fixture(scope="module")
def tiny_case() -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    return (
        torch.load(TINY / "inputs.pt", weights_only=True),
        torch.load(TINY / "outputs.pt", weights_only=True),
    )


def single_thread_forward(model: torch.nn.Module, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return lead.forward(model, inputs)
    finally:
        torch.set_num_threads(threads)


def test_tiny_ltfv6_reproduces_leads_outputs(tiny_case) -> None:
    inputs, expected = tiny_case
    model = lead.load_checkpoint(TINY)
    got = single_thread_forward(model, inputs)
    assert set(got) == set(expected)
    for key, value in expected.items():
        assert got[key].dtype == torch.float32
        torch.testing.assert_close(got[key], value, rtol=1e-5, atol=1e-5, msg=key)


def test_tiny_ltfv6_intermediates(tiny_case) -> None:
    inputs, _ = tiny_case
    stages = torch.load(TINY / "intermediates.pt", weights_only=True)
    model = lead.load_checkpoint(TINY)
    with torch.inference_mode():
        bev, image = model.backbone(inputs)
        context = model.planning_decoder.planning_context_encoder(bev, inputs)
    torch.testing.assert_close(bev, stages["backbone[0]"], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(image, stages["backbone[1]"], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(context, stages["planning_decoder.planning_context_encoder"], rtol=1e-5, atol=1e-5)


def test_ensemble_merges_as_lead(tmp_path: Path, tiny_case) -> None:
    inputs, _ = tiny_case
    shutil.copy(TINY / "config.json", tmp_path / "config.json")
    shutil.copy(TINY / "model_0000.pth", tmp_path / "model_0030_0.pth")
    state = torch.load(TINY / "model_0000.pth", weights_only=True)
    shifted = {k: v + 0.01 if v.is_floating_point() else v for k, v in state.items()}
    torch.save(shifted, tmp_path / "model_0030_1.pth")
    torch.save(shifted, tmp_path / "optimizer_0030.pth")  # not a model file: ignored
    ensemble = lead.load_checkpoint(tmp_path)
    assert isinstance(ensemble, lead.LeadEnsemble) and len(ensemble.members) == 2
    merged = lead.forward(ensemble, inputs)
    a, b = (lead.forward(m, inputs) for m in ensemble.members)
    assert not torch.equal(a["pred_future_waypoints"], b["pred_future_waypoints"])
    torch.testing.assert_close(
        merged["pred_future_waypoints"], (a["pred_future_waypoints"] + b["pred_future_waypoints"]) / 2
    )
    torch.testing.assert_close(merged["pred_headings"], (a["pred_headings"] + b["pred_headings"]) / 2)
    bev = merged["pred_bev_semantic_navsim"]
    torch.testing.assert_close(
        bev[:, 0], torch.minimum(a["pred_bev_semantic_navsim"][:, 0], b["pred_bev_semantic_navsim"][:, 0])
    )
    torch.testing.assert_close(
        bev[:, 1:], torch.maximum(a["pred_bev_semantic_navsim"][:, 1:], b["pred_bev_semantic_navsim"][:, 1:])
    )
    single = lead.load_checkpoint(tmp_path, pattern="model_0030_0.pth")
    torch.testing.assert_close(lead.forward(single, inputs)["pred_future_waypoints"], a["pred_future_waypoints"])


def test_export_round_trip(tmp_path: Path, tiny_case) -> None:
    inputs, _ = tiny_case
    model = lead.model_from_config(json.loads((TINY / "config.json").read_text())).eval()
    lead.export_checkpoint(model, tmp_path / "out")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["config.json", "model_0000.pth"]
    written = json.loads((tmp_path / "out" / "config.json").read_text())
    lead_file = json.loads((TINY / "config.json").read_text())
    shared = set(written) & set(lead_file)
    assert len(shared) > 80
    assert {k: written[k] for k in shared} == {k: lead_file[k] for k in shared}
    state = torch.load(tmp_path / "out" / "model_0000.pth", weights_only=True)
    assert type(state) is dict or isinstance(state, dict)
    assert all(v.is_contiguous() for v in state.values())
    again = lead.load_checkpoint(tmp_path / "out")
    expected = lead.forward(model, inputs)
    got = lead.forward(again, inputs)
    assert all(torch.equal(got[k], expected[k]) for k in expected)


def test_bad_folders_are_user_errors(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"no config\.json"):
        lead.load_checkpoint(tmp_path)
    shutil.copy(TINY / "config.json", tmp_path / "config.json")
    with pytest.raises(UserError, match="no file matches"):
        lead.load_checkpoint(tmp_path)
    values = json.loads((TINY / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps(dict(values, transfuser_token_dim=64)))
    shutil.copy(TINY / "model_0000.pth", tmp_path / "model_0000.pth")
    with pytest.raises(UserError, match=r"model_0000\.pth: does not match"):
        lead.load_checkpoint(tmp_path)


def _directory_entry(data: bytes, offset: int, value: bytes) -> bytes:
    """``data`` (a zip) with ``value`` written at ``offset`` in the central-directory entry of its first member."""
    at = data.index(b"PK\x01\x02") + offset
    return data[:at] + value + data[at + len(value) :]


def _utf8_flagged_name(data: bytes) -> bytes:
    """The first member's name marked UTF-8 (flag bit 11) and made of a byte that is not."""
    return _directory_entry(_directory_entry(data, 8, (0x800).to_bytes(2, "little")), 46, b"\xff")


def _directory_far_ahead(data: bytes) -> bytes:
    """The zip64 end record's offset of the central directory moved 1 TB on: members before the file's start."""
    at = data.rindex(b"PK\x06\x06") + 48
    return data[:at] + (2**40).to_bytes(8, "little") + data[at + 8 :]


def _last_data_past_the_end(data: bytes) -> bytes:
    """The last member's local header with 32 kB more of "extra field": its data starts past the file's end."""
    at = zipfile.ZipFile(io.BytesIO(data)).infolist()[-1].header_offset + 28
    extra = int.from_bytes(data[at : at + 2], "little") + 0x8000
    return data[:at] + extra.to_bytes(2, "little") + data[at + 2 :]


def _large_and_cut(data: bytes) -> bytes:
    """A 40 kB checkpoint cut at 20 kB: torch seeks before its start looking for the directory."""
    buffer = io.BytesIO()
    torch.save({"w": torch.zeros(10000)}, buffer)
    return buffer.getvalue()[:20000]


def _with_record(data: bytes, suffix: str, content: bytes) -> bytes:
    """A whole archive (valid CRCs) whose member ending in ``suffix`` holds ``content``."""
    source, out = zipfile.ZipFile(io.BytesIO(data)), io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name in source.namelist():
            archive.writestr(name, content if name.endswith(suffix) else source.read(name))
    return out.getvalue()


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda data: data.replace(np.float32(1234.5).tobytes(), np.float32(1234.75).tobytes()), "fails its CRC"),
        (lambda data: _directory_entry(data, 0, b"PK\x01\x03"), "damaged zip.*BadZipFile"),
        (_utf8_flagged_name, "damaged zip.*UnicodeDecodeError"),
        (_directory_far_ahead, "damaged zip.*OSError"),
        (_last_data_past_the_end, "damaged zip.*EOFError"),
        (lambda data: _directory_entry(data, 8, b"\x01\x00"), "damaged zip.*RuntimeError.*encrypted"),
        (lambda data: _directory_entry(data, 10, b"\x08\x00"), "damaged zip.*error.*decompressing"),  # zlib.error
        (lambda data: _directory_entry(data, 10, (99).to_bytes(2, "little")), "damaged zip.*NotImplementedError"),
        (lambda data: data[: len(data) // 2], "not a readable torch checkpoint.*central directory"),  # RuntimeError
        (_large_and_cut, "not a readable torch checkpoint.*Invalid argument"),  # OSError
        (lambda data: b"garbage", "not a readable torch checkpoint.*Weights only load failed"),  # UnpicklingError
        (lambda data: b"", r"not a readable torch checkpoint \(\)"),  # EOFError
        (lambda data: _with_record(data, "/.storage_alignment", b"x"), "torch checkpoint.*invalid literal for int"),
        (lambda data: _with_record(data, "/byteorder", b"\xff"), "torch checkpoint.*'utf-8' codec"),  # ValueError
    ],
)
def test_a_damaged_weight_file_is_named(tmp_path: Path, damage, message: str) -> None:
    """torch reads a zip without checking its CRCs: a bit flipped in a weight would load as another weight; zipfile
    and torch raise each of these on some damage of the archive's directory or records."""
    path = tmp_path / "model_0000.pth"
    torch.save({"w": torch.tensor([1.0, 1234.5])}, path)
    assert lead.read_weights(path)["w"][1] == 1234.5
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(UserError, match=rf"model_0000\.pth: .*{message}"):
        lead.read_weights(path)


def test_a_weight_file_of_something_else_is_named(tmp_path: Path) -> None:
    torch.save([torch.zeros(2)], tmp_path / "model_0000.pth")
    with pytest.raises(UserError, match=r"model_0000\.pth: holds a list, not the state_dict"):
        lead.read_weights(tmp_path / "model_0000.pth")


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [("n_layer", "x", "int"), ("use_depth", 7, "bool"), ("used_cameras", [1], "a list of bool"),
     ("pixels_per_meter", True, "float"), ("carla_root", None, "str")],
)  # fmt: skip
def test_a_wrong_typed_config_field_is_named(tmp_path: Path, field: str, value, expected: str) -> None:
    """LEAD's cast would read 7 as True, and "x" fails deep in a constructor."""
    values = json.loads((TINY / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps(dict(values, **{field: value})))
    with pytest.raises(UserError, match=rf"config\.json: {field} is .*; LEAD writes it as {expected}"):
        lead.read_config(tmp_path)


def test_a_config_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    (tmp_path / "config.json").write_bytes(b'{"n_layer": "\xff"}')
    with pytest.raises(UserError, match=r"config\.json: not valid JSON"):
        lead.read_config(tmp_path)


@pytest.mark.parametrize("name", sorted(CASES))
def test_carla_tfv6_with_radar_and_tfv5_reproduce_leads_outputs(name: str) -> None:
    """LEAD's TFv6 with LiDAR and radar, and TFv5, on seeded weights: outputs computed by LEAD's code (README)."""
    model = lead.model_from_config(CASES[name])
    model.load_state_dict(seeded_state(model.state_dict()), strict=True)
    expected = torch.load(DATA / f"reference_{name}.pt", weights_only=True)
    got = single_thread_forward(model.eval(), seeded_inputs(CASES[name]))
    assert set(got) == set(expected)
    assert expected["pred_radar_predictions"][..., :2].abs().max() > 1.0
    for key, value in expected.items():
        torch.testing.assert_close(got[key], value, rtol=1e-5, atol=1e-5, msg=key)
