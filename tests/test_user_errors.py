"""Every verb reports a mistake the user can fix as one line naming it, with exit status 2 and no traceback.

Lightning is imported at collection so that its log handler binds to pytest's stderr, not to the ``capsys`` of the
first fit test (closed when that test ends, after which every Lightning log line would be a logging traceback).
"""

import re
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from tiny_models import LTFV6_SWITCHES, TOY_LTFV6
from toy_adapter import ToyAdapter, corrupt_header, toy_sample, write_toy_logs

from lead_s2r import cli
from lead_s2r.cli import data as cli_data
from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.predictions import Prediction, write_predictions
from lead_s2r.shards import SHARD_DIR, ShardFile
from lead_s2r.training import cli as training_cli  # noqa: F401 - see the module docstring

WOD = "rfs@wod-e2e-2025"


def user_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``lead-s2r argv``, check the user-error contract and return the one line."""
    status = cli.main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2, captured.err
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    return lines[0]


@pytest.fixture
def toy_registered(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cli_data, "load", lambda name: ToyAdapter)


def convert_argv(src: Path, out: Path, *options: str) -> list[str]:
    return ["convert", "toy", "--src", str(src), "--out", str(out), "--quiet", *options]


# --------------------------------------------------------------------------- convert


def test_convert_missing_src(tmp_path, toy_registered, capsys):
    line = user_error(convert_argv(tmp_path / "nowhere", tmp_path / "out"), capsys)
    assert f"--src {tmp_path / 'nowhere'} does not exist" in line
    assert not (tmp_path / "out").exists()


def test_convert_empty_src_is_an_error_not_zero_samples(tmp_path, toy_registered, capsys):
    (tmp_path / "src").mkdir()
    line = user_error(convert_argv(tmp_path / "src", tmp_path / "out"), capsys)
    assert f"--src {tmp_path / 'src'} is an empty folder" in line
    (tmp_path / "src" / "README").write_text("no logs here")
    line = user_error(convert_argv(tmp_path / "src", tmp_path / "out"), capsys)
    assert "finds no logs" in line and str(tmp_path / "src") in line
    assert not (tmp_path / "out").exists()


def test_convert_bad_option_value(tmp_path, toy_registered, capsys):
    write_toy_logs(tmp_path / "src", n_logs=1, frames=2)
    line = user_error(convert_argv(tmp_path / "src", tmp_path / "out", "--sleep", "soon"), capsys)
    assert "--sleep" in line and "'soon'" in line
    line = user_error(convert_argv(tmp_path / "src", tmp_path / "out", "--workers", "many"), capsys)
    assert "--workers" in line and "'many'" in line
    assert not (tmp_path / "out").exists()


def test_convert_bad_value_rejected_by_the_adapter(tmp_path, capsys):
    argv = ["convert", "carla_lead", "--src", str(tmp_path), "--out", str(tmp_path / "out"), "--rig", "sideways"]
    line = user_error(argv, capsys)
    assert "adapter carla_lead" in line and "rig" in line and "'sideways'" in line


def test_convert_unknown_adapter_option(tmp_path, toy_registered, capsys):
    line = user_error(convert_argv(tmp_path, tmp_path / "out", "--rig", "both"), capsys)
    assert "unknown option '--rig' for adapter toy; it takes: --sleep" in line


def test_convert_unwritable_out(tmp_path, toy_registered, capsys):
    write_toy_logs(tmp_path / "src", n_logs=1, frames=2)
    (tmp_path / "file").write_text("a file, not a folder")
    line = user_error(convert_argv(tmp_path / "src", tmp_path / "file" / "out"), capsys)
    assert f"--out {tmp_path / 'file' / 'out'}: cannot write there" in line


def test_debug_shows_the_traceback(tmp_path, toy_registered):
    with pytest.raises(UserError, match="does not exist"):
        cli.main([*convert_argv(tmp_path / "nowhere", tmp_path / "out"), "--debug"])


# --------------------------------------------------------------------------- inspect


def test_inspect_missing_folder(tmp_path, capsys):
    line = user_error(["inspect", str(tmp_path / "nowhere")], capsys)
    assert f"{tmp_path / 'nowhere'} is not a folder" in line


def test_inspect_empty_folder(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    line = user_error(["inspect", str(tmp_path / "empty")], capsys)
    assert f"{tmp_path / 'empty'} holds no manifest.parquet" in line


def write_shard(folder: Path, samples: list[dict]) -> Path:
    (folder / SHARD_DIR).mkdir(parents=True)
    shard = ShardFile(folder / SHARD_DIR / "toy-000000.tar")
    for sample in samples:
        shard.write(sample)
    return shard.close()


def test_truncated_shard_names_the_tar(tmp_path, toy_data, capsys):
    shard = write_shard(tmp_path / "data", [toy_sample("log000", frame) for frame in range(3)])
    data = shard.read_bytes()
    for cut in (len(data) // 2, len(data) - 700):  # inside a member, and past the last member
        shard.write_bytes(data[:cut])
        argv = ["score", "--metric", "ade", "--predictions", "p", "--data", str(shard), "--out", "o"]
        line = user_error(argv, capsys)
        assert f"{shard}: truncated tar" in line
    assert not Path("o").exists()


def test_shard_cut_inside_zeros_names_the_tar(tmp_path, capsys):
    """Cut at a block boundary inside a member of zeros: the tail looks like an end of archive, tarfile finds out."""
    sample = toy_sample("log000", 0)
    sample["lidar"] = np.zeros((4096, 4), np.float32)  # 64 KiB of zeros
    shard = write_shard(tmp_path / "data", [sample])
    data = shard.read_bytes()
    start = data.index(b"toy_log000_000000.lidar.npy")
    shard.write_bytes(data[: start + 16 * 1024 - start % 512])
    argv = ["score", "--metric", "ade", "--predictions", "p", "--data", str(shard), "--out", str(tmp_path / "o")]
    line = user_error(argv, capsys)
    assert f"{shard}: cannot be read (unexpected end of data); the tar is truncated or corrupt" in line


def test_wrong_dtype_member_names_key_and_field(tmp_path, capsys):
    sample = toy_sample("log000", 0)
    sample["future"] = sample["future"].astype(np.float64)  # the writer does not validate; a foreign tool might
    write_shard(tmp_path / "data", [toy_sample("log000", 1), sample])
    folder = tmp_path / "data"
    line = user_error(["score", "--metric", "ade", "--predictions", "p", "--data", str(folder), "--out", "o"], capsys)
    assert "sample 'toy_log000_000000', field 'future': dtype float64, but schema v1 stores float32" in line
    assert "toy-000000.tar" in line


def test_corrupt_header_mid_shard_names_the_tar(tmp_path, capsys):
    write_toy_logs(tmp_path / "src", n_logs=1, frames=3)
    convert(ToyAdapter(), tmp_path / "src", tmp_path / "data")
    (shard,) = (tmp_path / "data" / SHARD_DIR).glob("*.tar")
    corrupt_header(shard, "toy_log000_000002.meta.json")
    argv = ["score", "--metric", "ade", "--predictions", "p", "--data", str(tmp_path / "data"), "--out", "o"]
    line = user_error(argv, capsys)
    assert f"{shard}: sample 'toy_log000_000002', which the manifest lists in it, is not in the tar" in line
    assert not Path("o").exists()


# --------------------------------------------------------------------------- score


def score_argv(predictions: Path, data: str, out: Path, *extra: str) -> list[str]:
    return ["score", "--metric", "ade", "--predictions", str(predictions), "--data", data, "--out", str(out), *extra]


def toy_predictions(path: Path, keys: list[str], dataset: str = "toy") -> Path:
    t = np.arange(1, 9, dtype=np.float32) * 0.5
    xy = np.stack([5 * t, 0 * t], axis=-1)
    return write_predictions(path, [Prediction(key, dataset, t, xy, np.zeros_like(t)) for key in keys])


def test_score_wrong_columns(tmp_path, toy_data, capsys):
    pq.write_table(pa.table({"key": ["a"], "trajectory": [[0.0]]}), tmp_path / "p.parquet")
    line = user_error(score_argv(tmp_path / "p.parquet", toy_data, tmp_path / "out"), capsys)
    assert f"{tmp_path / 'p.parquet'}: missing column(s) ['dataset', 't', 'x', 'y', 'yaw']" in line
    assert not (tmp_path / "out").exists()


def test_score_nans(tmp_path, toy_data, capsys):
    t = [0.5 * i for i in range(1, 9)]
    columns = {"key": ["toy_log000_000000"], "dataset": ["toy"], "t": [t], "x": [[float("nan")] * 8]}
    pq.write_table(pa.table({**columns, "y": [[0.0] * 8], "yaw": [[0.0] * 8]}), tmp_path / "p.parquet")
    line = user_error(score_argv(tmp_path / "p.parquet", toy_data, tmp_path / "out"), capsys)
    assert "p.parquet: prediction 'toy_log000_000000': t, x, y must be finite" in line


def test_score_not_parquet(tmp_path, toy_data, capsys):
    (tmp_path / "p.csv").write_text("key,x\na,1\n")
    line = user_error(score_argv(tmp_path / "p.csv", toy_data, tmp_path / "out"), capsys)
    assert f"{tmp_path / 'p.csv'}: not a readable parquet file" in line


def test_score_unknown_metric(tmp_path, toy_data, capsys):
    argv = score_argv(tmp_path / "p.parquet", toy_data, tmp_path / "out")
    argv[2] = "pdms"
    line = user_error(argv, capsys)
    assert "no lead_s2r.scorers entry named 'pdms'; registered:" in line and "ade" in line


def test_score_unknown_or_malformed_option(tmp_path, toy_data, capsys):
    path = toy_predictions(tmp_path / "p.parquet", ["toy_log000_000000"])
    line = user_error(score_argv(path, toy_data, tmp_path / "out", "--option", "horizon=3"), capsys)
    assert "--metric ade: bad --option" in line and "'horizon'" in line and "length_seconds" in line
    line = user_error(score_argv(path, toy_data, tmp_path / "out", "--option", "horizon"), capsys)
    assert "--option 'horizon': expected KEY=VALUE" in line
    line = user_error(score_argv(path, toy_data, tmp_path / "out", "--metrc", "ade"), capsys)
    assert "unrecognized arguments: --metrc ade" in line
    assert not (tmp_path / "out").exists()


def test_score_predictions_of_another_data_set_only(tmp_path, toy_data, capsys):
    path = toy_predictions(tmp_path / "p.parquet", ["seg_a"], dataset="wod_e2e")
    line = user_error(score_argv(path, toy_data, tmp_path / "out"), capsys)
    assert f"{path}: no prediction for any sample of {toy_data}" in line


# --------------------------------------------------------------------------- fit


def fit_config(tmp_path: Path, train: dict) -> Path:
    network = {**TOY_LTFV6, **LTFV6_SWITCHES, "use_carla_data": True}  # LTFv6 + LEAD: reads CARLA batches too
    config = {
        "trainer": {"accelerator": "cpu", "max_epochs": 1, "default_root_dir": str(tmp_path / "run")},
        "model": {"model": {"class_path": "lead_s2r.models.lead_driver.LeadDriver", "init_args": {"config": network}}},
        "data": {"train": train, "schedule": {"anchors": {0: dict.fromkeys(train, 2)}, "global_batch_size": 2}},
    }
    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


@pytest.fixture
def plain_argv(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI warns when the process has other arguments


def test_fit_missing_shard_path(tmp_path, plain_argv, capsys):
    config = fit_config(tmp_path, {"carla": {"paths": [str(tmp_path / "nowhere")], "cameras": ["front"]}})
    line = user_error(["fit", "--config", str(config)], capsys)
    assert f"data.train.carla.paths: {tmp_path / 'nowhere'} does not exist" in line
    assert not (tmp_path / "run").exists()


def test_fit_source_the_model_does_not_know(tmp_path, toy_data, plain_argv, capsys):
    config = fit_config(tmp_path, {"carla_lead": {"paths": [toy_data], "cameras": ["front"]}})
    line = user_error(["fit", "--config", str(config)], capsys)
    assert "data.train.carla_lead: the model knows no source 'carla_lead'; name it one of ['carla'" in line
    assert not (tmp_path / "run").exists()


def test_fit_missing_config_file_or_bad_value(tmp_path, plain_argv, capsys):
    line = user_error(["fit", "--config", str(tmp_path / "nope.yaml")], capsys)
    assert f"File does not exist: '{tmp_path / 'nope.yaml'}' (see lead-s2r fit --help)" in line
    config = fit_config(tmp_path, {"carla": {"paths": [str(tmp_path)], "cameras": ["front"]}})
    line = user_error(["fit", "--config", str(config), "--trainer.max_epochs", "many"], capsys)
    assert 'Parser key "trainer.max_epochs"' in line and "Given value: many" in line


def test_fit_config_with_a_wrong_typed_value_or_bytes_not_utf8_names_the_file(tmp_path, plain_argv, capsys):
    """jsonargparse names the key but not the file (a recipe may be one of several --config), and raised the
    decoder's own error for bytes that are not UTF-8."""
    config = fit_config(tmp_path, {"carla": {"paths": [str(tmp_path)], "cameras": ["front"]}})
    values = yaml.safe_load(config.read_text())
    values["data"]["schedule"]["global_batch_size"] = "x"
    config.write_text(yaml.safe_dump(values))
    line = user_error(["fit", "--config", str(config)], capsys)
    assert 'Parser key "data.schedule"' in line and f"--config {config}; see lead-s2r fit --help" in line
    config.write_bytes(config.read_bytes().replace(b"accelerator: cpu", b"accelerator: \xffcpu"))
    line = user_error(["fit", f"--config={config}"], capsys)
    assert line.startswith(f"error: --config {config}: not UTF-8 text ('utf-8' codec can't decode byte 0xff")


MODEL_CONFIG = ("model", "model", "init_args", "config")


def fit_config_with(tmp_path: Path, where: tuple, value: object) -> Path:
    """:func:`fit_config` (of a data folder that does not exist) with the value at keys ``where`` replaced."""
    config = fit_config(tmp_path, {"carla": {"paths": [str(tmp_path / "no-data")], "cameras": ["front"]}})
    values = yaml.safe_load(config.read_text())
    node = values
    for name in where[:-1]:
        node = node[name]
    node[where[-1]] = value
    config.write_text(yaml.safe_dump(values))
    return config


@pytest.mark.parametrize(
    ("where", "value", "message"),
    [
        ((*MODEL_CONFIG, "transfuser_num_bev_cross_attention_heads"), 7, "embed_dim must be divisible by num_heads"),
        ((*MODEL_CONFIG, "transfuser_token_dim"), None, "transfuser_token_dim"),  # was a TypeError in torch
        ((*MODEL_CONFIG, "image_architecture"), "x", "'x' is no timm architecture"),  # was a RuntimeError
        (("data", "train"), {}, r"no training sources configured \(data\.train\)"),  # was a ValueError at fit
    ],
)
def test_fit_config_value_no_constructor_can_use_names_the_file(tmp_path, plain_argv, capsys, where, value, message):
    """Values of the right YAML type for jsonargparse that the classes cannot be built with: each was a traceback."""
    config = fit_config_with(tmp_path, where, value)
    line = user_error(["fit", "--config", str(config)], capsys)
    assert re.search(message, line) and line.endswith(f"(--config {config})"), line


@pytest.mark.parametrize(
    ("where", "value"),
    [
        (("data",), 7),  # was jsonargparse's "argument after ** must be a mapping, not int"
        (("data",), [1]),
        (("trainer",), 7),  # was dropped unread: the run trained with the default trainer
        (("model", "model", "init_args"), True),  # was "'bool' object has no attribute 'keys'"
    ],
)
def test_fit_config_section_that_is_no_mapping_is_named_in_our_words(tmp_path, plain_argv, capsys, where, value):
    config = fit_config_with(tmp_path, where, value)
    line = user_error(["fit", "--config", str(config)], capsys)
    assert (
        line
        == f"error: --config {config}: {'.'.join(where)} is {value!r}, not a mapping of its settings (key: value lines)"
    )
    assert not (tmp_path / "run").exists()


def test_init_from_matching_no_tensor_is_refused_not_trained_from_random_weights(
    tmp_path, toy_data, plain_argv, capsys
):
    import torch

    config = fit_config(tmp_path, {"carla": {"paths": [toy_data], "cameras": ["front"]}})  # built before the model
    other = tmp_path / "other.ckpt"
    torch.save({"state_dict": {"encoder.weight": torch.zeros(3), "encoder.bias": torch.zeros(3)}}, other)
    line = user_error(["fit", "--config", str(config), f"--model.init_from={other}"], capsys)
    assert f"init_from: {other}: no tensor name matches the model" in line and "['network.encoder.']" in line
    assert "'network.backbone.'" in line and "'network.planning_decoder.'" in line  # the names the file should have
    line = user_error(["fit", "--config", str(config), f"--model.init_from={tmp_path / 'gone.ckpt'}"], capsys)
    assert f"init_from: no checkpoint at {tmp_path / 'gone.ckpt'}" in line
    assert not (tmp_path / "run").exists()
