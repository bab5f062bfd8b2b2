"""LEAD's checkpoints in our models: parameter tables of eight LEAD configurations, forward parity (every head and every
intermediate stage) with cases computed by LEAD's own code (tests/data/lead_tfv6/, README there), config derivation,
ensembles merged as LEAD's inference merges them, and export-lead: what it writes LEAD's own loader read strictly and
ran to our outputs; what LEAD cannot represent, or a damaged run checkpoint, is one line and nothing written."""

import io
import json
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from lead_reference import CASES, ENSEMBLES, EXPORTS, TINY_CARLA, TINY_NAVSIM, seeded_inputs, seeded_state, thinned
from lightning import __version__ as lightning_version
from torch import Tensor

from lead_s2r import cli
from lead_s2r.errors import UserError
from lead_s2r.models import lead
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.training.lead_export import check_lead_reads
from lead_s2r.training.module import DrivingModule

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
    small = LeadConfig.from_json({**TINY_CARLA, "camera_tile_size": [64, 32]})
    assert (small.final_image_height, small.final_image_width) == (32, 192)
    assert (small.img_vert_anchors, small.img_horz_anchors) == (1, 6)
    assert LeadConfig.from_json(small.to_json()) == small
    assert LeadConfig.from_json(TINY_CARLA).final_image_width == 1152
    full = lead.model_from_config(TINY_CARLA).state_dict()
    model = lead.model_from_config({**TINY_CARLA, "camera_tile_size": [64, 32]})
    changed = {k for k, v in model.state_dict().items() if v.shape != full[k].shape}
    assert model.state_dict().keys() == full.keys() and changed and all("pos_emb" in k for k in changed), changed
    inputs = seeded_inputs(TINY_CARLA)
    inputs["rgb"] = inputs["rgb"][:, :, :32, :192]
    outputs = lead.forward(model.eval(), inputs)
    assert outputs["pred_future_waypoints"].shape == (1, 8, 2)
    for bad in ([64, 48], [64], [0, 64]):
        with pytest.raises(UserError, match="camera_tile_size"):
            LeadConfig.from_json({"camera_tile_size": bad})


def test_toy_scales_scale_the_planners_status_inputs_and_outputs() -> None:
    """Our toy scales (the smoke twins'): the same weights with ``trajectory_scale`` 8 and ``heading_scale`` 0.1 give 8
    times the waypoints and a tenth of the headings; ``status_scale`` 4 reads speed and acceleration as 4 times
    larger. Each refused below 0; LEAD's network is all three at 1."""
    inputs = seeded_inputs(TINY_NAVSIM)
    lead_model = seeded_model(TINY_NAVSIM)
    plain = lead.forward(lead_model, inputs)
    toy = lead.model_from_config({**TINY_NAVSIM, "trajectory_scale": 8.0, "heading_scale": 0.1, "status_scale": 4.0})
    toy.load_state_dict(lead_model.state_dict(), strict=True)
    faster = {**inputs, "speed": inputs["speed"] * 4, "acceleration": inputs["acceleration"] * 4}
    expected = lead.forward(lead_model, faster)
    got = lead.forward(toy.eval(), inputs)
    torch.testing.assert_close(got["pred_future_waypoints"], 8 * expected["pred_future_waypoints"])
    torch.testing.assert_close(got["pred_headings"], 0.1 * expected["pred_headings"])
    assert not torch.allclose(expected["pred_future_waypoints"], plain["pred_future_waypoints"])
    for name in ("status_scale", "trajectory_scale", "heading_scale"):
        with pytest.raises(UserError, match=name):
            LeadConfig.from_json({name: 0.0})


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


def recorded_forward(
    model: torch.nn.Module, inputs: dict[str, Tensor], names: list[str]
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Our outputs and the stages LEAD's intermediates name: a module's output (``name``, or ``name[i]`` of a tuple)
    and ``backbone.top_down`` (a method, as in LEAD)."""
    stages: dict[str, Tensor] = {}
    modules = dict(model.named_modules())

    def keep(name: str):
        def hook(_module, _inputs, output) -> None:
            items = [output] if isinstance(output, Tensor) else list(output)
            for i, item in enumerate(items):
                stages[name if isinstance(output, Tensor) else f"{name}[{i}]"] = item

        return hook

    hooked = {name.split("[")[0] for name in names} - {"backbone.top_down"}
    handles = [modules[name].register_forward_hook(keep(name)) for name in hooked]
    top_down = model.backbone.top_down
    if "backbone.top_down" in names:
        model.backbone.top_down = lambda bev: stages.setdefault("backbone.top_down", top_down(bev))
    try:
        return single_thread_forward(model, inputs), stages
    finally:
        vars(model.backbone).pop("top_down", None)
        for handle in handles:
            handle.remove()


def assert_all_close(got: dict[str, Tensor], expected: dict[str, Tensor]) -> None:
    assert set(got) == set(expected), set(got) ^ set(expected)
    for key, value in expected.items():
        torch.testing.assert_close(got[key], value, rtol=1e-5, atol=1e-5, msg=key)


def test_tiny_ltfv6_intermediates(tiny_case) -> None:
    """Every stage LEAD's hooks recorded, the planner's transformer decoder included."""
    inputs, _ = tiny_case
    stages = torch.load(TINY / "intermediates.pt", weights_only=True)
    assert "planning_decoder.transformer_decoder" in stages
    _, got = recorded_forward(lead.load_checkpoint(TINY), inputs, list(stages))
    assert_all_close(got, stages)


def seeded_model(overrides: dict, seed: int = 0) -> torch.nn.Module:
    model = lead.model_from_config(overrides)
    model.load_state_dict(seeded_state(model.state_dict(), seed), strict=True)
    return model.eval()


def test_ensemble_of_a_folder_merges_navsim_as_lead(tmp_path: Path, tiny_case) -> None:
    """A folder with two model files is an ensemble; in NAVSIM mode LEAD keeps waypoints and headings (averaged) and
    drops the BEV and box maps."""
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
    assert "pred_bev_semantic_navsim" in a and set(merged) == {"pred_future_waypoints", "pred_headings"}
    assert not torch.equal(a["pred_future_waypoints"], b["pred_future_waypoints"])
    for key in merged:
        torch.testing.assert_close(merged[key], (a[key] + b[key]) / 2)
    single = lead.load_checkpoint(tmp_path, pattern="model_0030_0.pth")
    torch.testing.assert_close(lead.forward(single, inputs)["pred_future_waypoints"], a["pred_future_waypoints"])


@pytest.mark.parametrize("name", sorted(ENSEMBLES))
def test_ensemble_merges_as_leads_inference_per_mode(name: str) -> None:
    """Two seeded members merged by LEAD's own ``OpenLoopInference.ensemble`` (ensemble_<name>.pt): CARLA leaderboard
    mode merges the semantic maps (background min, others max) and averages depth (its CenterNet maps, averaged, stand
    in for LEAD's NMS of decoded boxes); NAVSIM keeps only the planner.
    LEAD returns the averaged target-speed logits' softmax (we keep the logits) and forces the speed to 0 above its
    brake threshold, which these members do not reach."""
    golden = torch.load(DATA / f"ensemble_{name}.pt", weights_only=True)
    members = [seeded_model(ENSEMBLES[name], seed) for seed in (0, 1)]
    got = thinned(single_thread_forward(lead.LeadEnsemble(members), seeded_inputs(ENSEMBLES[name])))
    expected = {("pred_headings" if k == "pred_future_headings" else k): v for k, v in golden["outputs"].items()}
    if "pred_target_speed_distribution" in expected:
        probabilities = expected.pop("pred_target_speed_distribution")
        assert probabilities[0, 0] <= golden["brake_threshold"]
        torch.testing.assert_close(got.pop("pred_target_speed_distribution").softmax(-1), probabilities)
        expected["pred_target_speed_scalar"] = expected["pred_target_speed_scalar"].reshape(-1)
    boxes = {key: got.pop(key) for key in list(got) if key.startswith("pred_bounding_box")}  # LEAD: NMS of boxes
    assert_all_close(got, expected)
    assert ("pred_bev_semantic" in got) == bool(boxes) == (name == "carla")


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


@pytest.mark.parametrize("name", sorted(EXPORTS))
def test_an_export_is_what_leads_loader_read_and_ran(tmp_path: Path, name: str) -> None:
    """LEAD's own loader read this export (config.json -> TrainingConfig -> TFv6, strict load of model_0000.pth) and
    its forward gave export_<name>.pt; the same export reloaded by ours gives the same outputs."""
    golden = torch.load(DATA / f"export_{name}.pt", weights_only=True)
    assert json.loads(golden["overrides"]) == EXPORTS[name]
    model = seeded_model(EXPORTS[name])
    check_lead_reads(model.config, tmp_path)
    lead.export_checkpoint(model, tmp_path / "out")
    got = single_thread_forward(lead.load_checkpoint(tmp_path / "out"), seeded_inputs(EXPORTS[name]))
    assert_all_close(thinned(got), golden["outputs"])


def test_fields_at_leads_own_values_are_exported() -> None:
    """Our extension fields set to what LEAD's rules derive anyway are no obstacle."""
    same = {**TINY_CARLA, "num_way_points_prediction": 8, "waypoint_interval_s": 0.25, "camera_tile_size": [384, 384]}
    check_lead_reads(LeadConfig.from_json({**same, "use_previous_tp": True, "use_next_tp": True}), Path("run"))


def lead_run(root: Path, overrides: dict) -> Path:
    """A run folder as LightningCLI leaves it: checkpoints/last.ckpt whose hyper_parameters name the LeadDriver and
    its config, with seeded weights."""
    driver = LeadDriver(LeadConfig.from_json(overrides))
    driver.network.load_state_dict(seeded_state(driver.network.state_dict()), strict=True)
    model = {"class_path": "lead_s2r.models.lead_driver.LeadDriver", "init_args": {"config": overrides}}
    hyper_parameters = {"_instantiator": "lightning.pytorch.cli.instantiate_module", "model": model}
    saved = {"state_dict": DrivingModule(model=driver).state_dict(), "hyper_parameters": hyper_parameters}
    (root / "checkpoints").mkdir(parents=True)
    torch.save({**saved, "pytorch-lightning_version": lightning_version}, root / "checkpoints" / "last.ckpt")
    return root


def test_export_lead_of_a_smoke_run_writes_what_lead_read(tmp_path: Path, capsys) -> None:
    run = lead_run(tmp_path / "run", EXPORTS["navsim_smoke"])
    assert cli.main(["export-lead", str(run), "--out", str(tmp_path / "lead")]) == 0
    assert "LEAD ignores our keys waypoint_interval_s, camera_tile_size" in capsys.readouterr().out
    golden = torch.load(DATA / "export_navsim_smoke.pt", weights_only=True)
    got = single_thread_forward(lead.load_checkpoint(tmp_path / "lead"), seeded_inputs(EXPORTS["navsim_smoke"]))
    assert_all_close(thinned(got), golden["outputs"])


def assert_refused(argv: list[str], out: Path, capsys, *words: str) -> None:
    """Exit status 2, one stderr line naming each of ``words``, nothing written."""
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(word in err for word in words), err
    assert not out.exists()


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        # recipes/carla/tfv6_one_tp.yaml
        ({**TINY_CARLA, "use_previous_tp": False, "use_next_tp": False}, "use_previous_tp"),
        ({**TINY_CARLA, "use_next_tp": False}, "use_next_tp"),
        ({**TINY_CARLA, "camera_tile_size": [64, 64]}, "camera_tile_size"),  # the smoke twins' overlay
        ({**TINY_NAVSIM, "num_way_points_prediction": 12}, "num_way_points_prediction"),
        ({**TINY_NAVSIM, "waypoint_interval_s": 0.25}, "waypoint_interval_s"),  # loads in LEAD, means 0.5 s there
        ({**TINY_NAVSIM, "trajectory_scale": 8.0}, "trajectory_scale"),  # the smoke twins' toy scales
        ({**TINY_NAVSIM, "status_scale": 8.0}, "status_scale"),
        ({**TINY_NAVSIM, "heading_scale": 0.1}, "heading_scale"),
        ({**TINY_NAVSIM, "use_navsim_data": False, "use_waymo_e2e_data": True, "used_cameras": [True] * 3},
         "use_waymo_e2e_data"),
    ],
)  # fmt: skip
def test_export_lead_refuses_what_lead_cannot_represent(tmp_path: Path, capsys, overrides: dict, field: str) -> None:
    run = lead_run(tmp_path / "run", overrides)
    argv = ["export-lead", str(run), "--out", str(tmp_path / "lead")]
    assert_refused(argv, tmp_path / "lead", capsys, field, "last.ckpt", "nothing written")


def _flip_a_weight_bit(data: bytes, weight: Tensor) -> bytes:
    at = data.index(weight.flatten()[:4].numpy().tobytes())
    return data[:at] + bytes([data[at] ^ 1]) + data[at + 1 :]


@pytest.mark.parametrize("damage", ["flipped bit", "cut"])
def test_export_lead_of_a_damaged_checkpoint_is_one_line(tmp_path: Path, capsys, damage: str) -> None:
    run = lead_run(tmp_path / "run", EXPORTS["navsim_smoke"])
    last = run / "checkpoints" / "last.ckpt"
    data = last.read_bytes()
    weight = torch.load(last, weights_only=True)["state_dict"]["model.network.planning_decoder.query"]
    last.write_bytes(_flip_a_weight_bit(data, weight) if damage == "flipped bit" else data[: len(data) // 2])
    assert_refused(["export-lead", str(run), "--out", str(tmp_path / "lead")], tmp_path / "lead", capsys, "last.ckpt")


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


def test_a_config_value_of_its_type_that_no_layer_takes_is_named(tmp_path: Path) -> None:
    """The fuzz at seed 6911: a dropout probability of 7 (a number where LEAD writes a number) failed in torch."""
    shutil.copytree(TINY, tmp_path / "lead")
    values = json.loads((TINY / "config.json").read_text())
    (tmp_path / "lead" / "config.json").write_text(json.dumps(dict(values, resid_pdrop=7)))
    with pytest.raises(UserError, match=r"config\.json: LEAD's network cannot be built from it \(dropout probability"):
        lead.load_checkpoint(tmp_path / "lead")


def test_a_config_naming_no_timm_architecture_names_its_file(tmp_path: Path) -> None:
    """The fuzz at seed 10501: one flipped byte made ``test_sonvnext``, and the error named the field only."""
    values = json.loads((TINY / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps(dict(values, image_architecture="test_sonvnext")))
    with pytest.raises(
        UserError, match=rf"^{re.escape(str(tmp_path / 'config.json'))}: image_architecture 'test_sonvnext' is no timm"
    ):
        lead.read_config(tmp_path)


def test_a_config_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    (tmp_path / "config.json").write_bytes(b'{"n_layer": "\xff"}')
    with pytest.raises(UserError, match=r"config\.json: not valid JSON"):
        lead.read_config(tmp_path)


@pytest.mark.parametrize("name", sorted(CASES))
def test_carla_cases_reproduce_every_head_and_stage_of_leads_forward(name: str) -> None:
    """LEAD's TFv6 with LiDAR, radar and every head, and TFv5, on seeded weights: every output and every stage LEAD's
    forward passes through (backbone fusion per scale, BEV grid, planner context, decoder), computed by LEAD's code."""
    reference = torch.load(DATA / f"reference_{name}.pt", weights_only=True)
    expected, stages = reference["outputs"], reference["intermediates"]
    got, got_stages = recorded_forward(seeded_model(CASES[name]), seeded_inputs(CASES[name]), list(stages))
    assert expected["pred_radar_predictions"][..., :2].abs().max() > 1.0
    assert_all_close(got, expected)
    assert_all_close(got_stages, stages)


def test_every_head_and_stage_is_pinned() -> None:
    """The LEAD-computed cases together hold every output head and the decoder stage."""
    outputs = {key.split(".")[0] for key in torch.load(TINY / "outputs.pt", weights_only=True)}
    stages: set[str] = set()
    for name in CASES:
        reference = torch.load(DATA / f"reference_{name}.pt", weights_only=True)
        outputs |= {key.split(".")[0] for key in reference["outputs"]}
        stages |= set(reference["intermediates"])
    heads = {"pred_semantic", "pred_depth", "pred_bev_semantic", "pred_bev_semantic_navsim", "pred_bounding_box",
             "pred_bounding_box_navsim", "pred_radar_features", "pred_radar_predictions", "pred_route",
             "pred_future_waypoints", "pred_headings", "pred_target_speed_distribution",
             "pred_target_speed_scalar"}  # fmt: skip
    assert heads <= outputs, heads - outputs
    decoders = {"planning_decoder.transformer_decoder", "planning_decoder.wp_gru[0]", "planning_decoder.route_gru[0]"}
    assert decoders | {"backbone.top_down", "backbone.transformers.3[1]"} <= stages
