"""Damaged ``torch.save`` files are named, not loaded as other weights: LEAD weights, ``init_from``, the closed-loop
agent's checkpoint and ``ckpt_path`` (flag or config file) all read through :mod:`lead_s2r.formats.torch_file`.

Lightning is imported at collection, as in test_user_errors.py, so that its log handler binds to pytest's stderr.
"""

from pathlib import Path

import pytest
import torch
from test_user_errors import fit_config, plain_argv, user_error  # noqa: F401 - plain_argv is a fixture

from lead_s2r.closed_loop.checkpoint import load_model
from lead_s2r.errors import UserError
from lead_s2r.formats import torch_file
from lead_s2r.training import cli as training_cli  # noqa: F401 - see the module docstring
from lead_s2r.training.weights import read_state_dict


def checkpoint(path: Path) -> Path:
    """A Lightning-shaped checkpoint whose one tensor (64K floats) fills most of the file."""
    torch.save({"state_dict": {"model.w": torch.arange(65536, dtype=torch.float32)}}, path)
    return path


def flipped(path: Path) -> Path:
    """``path`` with one bit flipped in its middle, inside the tensor's bytes: torch alone loads it."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))
    return path


def test_a_flipped_bit_in_a_tensor_loads_with_torch_but_not_with_us(tmp_path):
    pristine = torch_file.load(checkpoint(tmp_path / "good.ckpt"))
    assert torch.equal(pristine["state_dict"]["model.w"], torch.arange(65536, dtype=torch.float32))
    damaged = flipped(checkpoint(tmp_path / "bad.ckpt"))
    silently = torch.load(damaged, weights_only=True)["state_dict"]["model.w"]
    assert not torch.equal(silently, pristine["state_dict"]["model.w"])  # the reason for the CRC check
    with pytest.raises(UserError, match=r"bad\.ckpt: its member .*data/0 fails its CRC check"):
        torch_file.load(damaged)


def test_a_cut_file_is_refused_as_an_archive_and_named_by_load(tmp_path):
    path = checkpoint(tmp_path / "cut.ckpt")
    path.write_bytes(path.read_bytes()[:5000])
    with pytest.raises(UserError, match=r"cut\.ckpt: not a torch checkpoint archive"):
        torch_file.check_archive(path, zip_only=True)
    with pytest.raises(UserError, match=r"cut\.ckpt: not a readable torch checkpoint"):
        torch_file.load(path)


def test_init_from_and_the_agent_name_a_damaged_checkpoint(tmp_path):
    damaged = flipped(checkpoint(tmp_path / "last.ckpt"))
    with pytest.raises(UserError, match=r"last\.ckpt: its member .* fails its CRC check"):
        read_state_dict(damaged)
    with pytest.raises(UserError, match=r"last\.ckpt: its member .* fails its CRC check"):
        load_model(damaged)
    torch.save([1, 2], tmp_path / "list.ckpt")
    with pytest.raises(UserError, match=r"list\.ckpt holds no state dict of tensors"):
        read_state_dict(tmp_path / "list.ckpt")


@pytest.mark.parametrize("given", ["flag", "config"])  # --ckpt_path, or ckpt_path: in a config file
@pytest.mark.parametrize("damage", ["flip", "cut"])
def test_predict_with_a_damaged_ckpt_path_is_one_line(tmp_path, toy_data, plain_argv, capsys, damage, given):  # noqa: F811
    config = fit_config(tmp_path, {"carla": {"paths": [toy_data], "cameras": ["front"]}})
    path = checkpoint(tmp_path / "last.ckpt")
    if damage == "flip":
        flipped(path)
    else:
        path.write_bytes(path.read_bytes()[:5000])
    weights = ["--ckpt_path", str(path)]
    if given == "config":
        (tmp_path / "weights.yaml").write_text(f"ckpt_path: {path}\n")
        weights = ["--config", str(tmp_path / "weights.yaml")]
    line = user_error(["predict", "--config", str(config), *weights], capsys)
    assert str(path) in line and ("CRC" in line if damage == "flip" else "not a torch checkpoint archive" in line)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "removed",
    [
        {"hyper_parameters": {"model": {"class_path": torch_file.REMOVED_NETWORK, "init_args": {}}}, "state_dict": {}},
        {"state_dict": {"model.backbone.image.stages.0.weight": torch.zeros(2)}},  # before hyper_parameters said
    ],
)
def test_a_checkpoint_of_the_removed_network_is_one_line_wherever_it_is_read(
    tmp_path,
    toy_data,
    plain_argv,  # noqa: F811
    capsys,
    removed,
):
    path = tmp_path / "old.ckpt"
    torch.save(removed, path)
    message = r"old\.ckpt: made by the removed TransFuser network \(lead_s2r\.models\.tfv6\.TFv6\)"
    for read in (read_state_dict, load_model, torch_file.load):  # init_from, the agent, every other reader
        with pytest.raises(UserError, match=message):
            read(path)
    config = fit_config(tmp_path, {"carla": {"paths": [toy_data], "cameras": ["front"]}})
    line = user_error(["predict", "--config", str(config), "--ckpt_path", str(path)], capsys)
    assert "made by the removed TransFuser network" in line and not (tmp_path / "run").exists()
    assert "made by the removed" in user_error(["export-lead", str(path), "--out", str(tmp_path / "lead")], capsys)
    assert not (tmp_path / "lead").exists()
