import json
import re

import cv2
import numpy as np
import pytest
from toy_adapter import ToyAdapter, write_toy_logs

from lead_s2r import cli
from lead_s2r.cli import data as cli_data
from lead_s2r.convert import convert
from lead_s2r.errors import UserError


@pytest.fixture
def toy_registered(monkeypatch):
    monkeypatch.setattr(cli_data, "load", lambda name: ToyAdapter)


def test_adapter_options_are_typed_by_the_constructor():
    assert cli_data.adapter_options(ToyAdapter, ["--sleep", "0.5"]) == {"sleep": 0.5}
    with pytest.raises(UserError, match=r"unknown option '--rig'.*--sleep"):
        cli_data.adapter_options(ToyAdapter, ["--rig", "both"])
    with pytest.raises(UserError, match="needs a value"):
        cli_data.adapter_options(ToyAdapter, ["--sleep"])


def test_convert_verb_exit_status_reports_failed_logs(tmp_path, toy_registered, capsys):
    write_toy_logs(tmp_path / "src", n_logs=3, frames=4, broken=(1,))
    argv = ["convert", "toy", "--src", str(tmp_path / "src"), "--out", str(tmp_path / "out"), "--quiet"]
    assert cli.main(argv) == 1
    captured = capsys.readouterr()
    assert "8 samples from 2 logs" in captured.out and "failed log001" in captured.err
    write_toy_logs(tmp_path / "src2", n_logs=2, frames=4)
    argv = ["convert", "toy", "--src", str(tmp_path / "src2"), "--out", str(tmp_path / "out2"), "--quiet"]
    assert cli.main(argv) == 0


def test_unknown_adapter_is_a_clear_error(capsys):
    assert cli.main(["convert", "nope", "--src", "x", "--out", "y"]) == 2
    assert re.fullmatch(
        r"error: no lead_s2r.adapters entry named 'nope'; registered: .*navsim.*\n", capsys.readouterr().err
    )


def test_inspect_reports_and_draws(tmp_path, capsys):
    write_toy_logs(tmp_path / "src", n_logs=2, frames=5)
    convert(ToyAdapter(), tmp_path / "src", tmp_path / "out")
    png = tmp_path / "sample.png"
    assert cli.main(["inspect", str(tmp_path / "out"), "--png", str(png), "--key", "toy_log001_000002"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["samples"] == 10 and report["logs"] == 2 and report["invalid"] == []
    assert report["by_dataset_split"] == {"toy/train": 10}
    assert report["fields_present"]["lidar"] == 10
    assert report["statistics"]["future_s"] == {"min": 4.0, "max": 4.0, "mean": 4.0}
    image = cv2.imread(str(png))
    assert image.shape[1] == 960 and image.shape[0] > 640  # the camera above the BEV
    # the logged future (green) is drawn ahead of the ego, i.e. above the ego box (its dark grey fill) in the BEV
    bev = image[-600:]  # the lower 6.4 in at 100 dpi hold the BEV
    future_rows = (bev == (81, 166, 0)).all(axis=2).nonzero()[0]
    ego_rows = (bev == (74, 74, 74)).all(axis=2).nonzero()[0]
    assert len(future_rows) and len(ego_rows) and np.median(future_rows) < ego_rows.min()
    assert cli.main(["inspect", str(tmp_path / "out"), "--png", str(png), "--key", "nope"]) == 2
    assert "--key 'nope': no sample with that key" in capsys.readouterr().err


def test_inspect_lists_keys_and_draws_the_sample_that_turns_most_by_default(tmp_path, capsys):
    write_toy_logs(tmp_path / "src", n_logs=2, frames=3)
    convert(ToyAdapter(), tmp_path / "src", tmp_path / "out")
    assert cli.main(["inspect", str(tmp_path / "out"), "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 6 and lines[4].split() == ["toy_log001_000001", "toy/train", "log001", "1", "5.00", "m/s"]
    assert cli.main(["inspect", str(tmp_path / "out"), "--png", str(tmp_path / "a.png")]) == 0
    assert json.loads(capsys.readouterr().out)["png_key"] == "toy_log000_000000"  # all turn alike: the first


def test_the_default_picture_is_the_sample_whose_future_turns_most():
    from lead_s2r.report.inspection import heading_change

    def sample(key: str, last: list[float] | None) -> dict:
        return {"__key__": key} | ({} if last is None else {"future": np.array([[0.5, 1, 0, 0], last], np.float32)})

    straight, left = sample("straight", [4, 20, 0, 0]), sample("left", [4, 15, 10, 0.9])
    right_no_yaw, parked = sample("right", [4, 10, -10, np.nan]), sample("parked", None)
    assert heading_change(right_no_yaw) == pytest.approx(np.pi / 4)  # the bearing of its last point
    assert heading_change(left) == pytest.approx(0.9) and heading_change(parked) == 0.0
    assert heading_change(left) > heading_change(right_no_yaw) > heading_change(straight) == 0.0


def test_adapters_says_which_extras_are_installed(monkeypatch, capsys):
    import importlib.metadata

    from lead_s2r.registry import missing_requirements

    listed = [
        'pyarrow>=1; extra == "a"',
        'surely-not-installed-xyz>=1; extra == "a"',
        'surely-not-installed-abc; extra == "b"',
        'surely-not-installed-old; python_version < "3.0" and extra == "a"',  # not for this Python
        "numpy>=1",  # not part of any extra
    ]
    monkeypatch.setattr(importlib.metadata, "requires", lambda distribution: listed)
    assert missing_requirements("a") == ["surely-not-installed-xyz"]
    assert missing_requirements("b") == ["surely-not-installed-abc"] and missing_requirements("c") == []
    assert cli_data._extra_state("b") == "b (missing surely-not-installed-abc: pip install 'lead-s2r[b]')"
    assert cli_data._extra_state(None) == "- (none needed)" and cli_data._extra_state("c") == "c (installed)"
