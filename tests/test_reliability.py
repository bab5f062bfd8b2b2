"""Issue 26, one test per finding: a silent loss, a crash or a traceback became a report naming the file (an
errors.jsonl line in ``convert``, one line and exit status 2 elsewhere), and wrong inputs that "succeeded" are errors.

Lightning is imported at collection, as in test_user_errors.py, so that its log handler binds to pytest's stderr.
"""

import io
import json
import lzma
import os
import pickle
import re
import struct
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from corruptions import aborting_laz, hardlink_copy
from test_user_errors import fit_config, plain_argv, user_error  # noqa: F401 - plain_argv is a fixture
from toy_adapter import ToyAdapter, write_toy_logs

from lead_s2r.convert import convert
from lead_s2r.data.streams import manifest_samples
from lead_s2r.formats import restricted_pickle
from lead_s2r.predictions import write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.report.inspection import inspect_dataset
from lead_s2r.schema import SchemaError, validate
from lead_s2r.scoring.baselines import predict_human
from lead_s2r.shards import ERRORS, INFO, MANIFEST, ShardError, load_manifest, read_samples
from lead_s2r.training import cli as training_cli  # noqa: F401 - see the module docstring

DATA = Path(__file__).parent / "data"
CLUSTERS = "val_sequence_name_to_scenario_cluster.json"


@pytest.fixture(scope="module")
def raw(tmp_path_factory) -> dict[str, Path]:
    """Small raw data of every adapter, never written by a test (tests corrupt hard-linked copies)."""
    from lead_s2r.synthetic import carla_lead, navsim, wod_e2e

    root = tmp_path_factory.mktemp("raw")
    carla_lead.generate(root / "carla_lead", count=2, seed=1, frames=3)
    navsim.generate(root / "navsim", count=2, seed=1)
    wod_e2e.generate(root / "wod_e2e", seed=1, splits={"train": 2, "val": 2})
    return {name: root / name for name in ("carla_lead", "navsim", "wod_e2e")}


@pytest.fixture(scope="module")
def converted(raw, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("converted")
    for name in ("navsim", "wod_e2e"):
        assert convert(get_adapter(name), raw[name], root / name, shard_size=8).ok
    return {name: root / name for name in ("navsim", "wod_e2e")}


def copy_of(folder: Path, tmp_path: Path) -> Path:
    hardlink_copy(folder, tmp_path / folder.name)
    return tmp_path / folder.name


def rewrite(path: Path, data: bytes) -> None:
    """Replace a hard-linked file without touching the shared original."""
    path.unlink()
    path.write_bytes(data)


def logs_of(folder: Path) -> set[str]:
    return set(load_manifest(folder)["log"].to_pylist())


def routes(src: Path) -> list[Path]:
    return sorted(p for p in (src / "data").glob("*/*") if p.is_dir())


# --------------------------------------------------------------------------- silent losses


def test_wod_shard_set_short_of_a_file_fails_its_segments_naming_the_file(raw, tmp_path):
    src = copy_of(raw["wod_e2e"], tmp_path)
    gone = next(src.glob("training_*.tfrecord-00001-of-00003"))
    gone.unlink()
    result = convert(get_adapter("wod_e2e"), src, tmp_path / "out")
    assert not result.ok and len(result.errors) == 2  # both training segments, each naming the missing file
    assert all(str(gone) in error["error"] and "(at " not in error["error"] for error in result.errors)
    assert set(load_manifest(tmp_path / "out")["split"].to_pylist()) == {"val"}  # the complete split converts


def test_missing_shard_tar_is_named_by_every_reader(converted, tmp_path):
    folder = copy_of(converted["wod_e2e"], tmp_path)
    gone = sorted((folder / "shards").glob("*.tar"))[1]
    gone.unlink()
    for read in (
        lambda: list(read_samples(folder)),
        lambda: inspect_dataset(folder),
        lambda: manifest_samples(folder, None),
    ):
        with pytest.raises(ShardError, match=f"{gone}: missing, but manifest.parquet lists"):
            read()


def test_tar_cut_mid_sample_is_an_error_not_a_short_sample(converted, tmp_path, capsys):
    """A zeroed tar header ends tarfile's stream quietly: the sample before it came out short of fields."""
    folder = copy_of(converted["wod_e2e"], tmp_path)
    shard = sorted((folder / "shards").glob("*.tar"))[0]
    data = bytearray(shard.read_bytes())
    at = data.index(b".future.npy") // 512 * 512  # the header block of the first sample's future
    data[at : at + 512] = bytes(512)
    rewrite(shard, bytes(data))
    with pytest.raises(ShardError, match=rf"{shard}: sample '\w+': field '(future|past)' is missing from the tar"):
        list(read_samples(folder, fields=("future",)))
    assert str(shard) in user_error(["inspect", str(folder)], capsys)  # the progress bar adds no line off a terminal


def test_lead_deleted_frame_or_sensor_file_is_named(raw, tmp_path):
    src = copy_of(raw["carla_lead"], tmp_path)
    first, second = routes(src)
    (first / "bboxes" / "0001.pkl").unlink()
    (second / "rgb" / "0002.jpg").unlink()
    result = convert(get_adapter("carla_lead"), src, tmp_path / "out")
    errors = {error["log"]: error["error"] for error in result.errors}
    assert len(errors) == 2
    assert f"{first / 'bboxes' / '0001.pkl'}: missing" in errors[f"{first.parent.name}/{first.name}"]
    assert f"{second / 'rgb' / '0002.jpg'}: missing" in errors[f"{second.parent.name}/{second.name}"]


def test_navsim_log_pickle_deleted_is_reported(raw, tmp_path):
    src = copy_of(raw["navsim"], tmp_path)
    pickle_path = sorted((src / "navsim_logs" / "mini").glob("*.pkl"))[0]
    pickle_path.unlink()
    result = convert(get_adapter("navsim"), src, tmp_path / "out")
    assert not result.ok and len(result.bad_records) == 1
    assert f"which has no log pickle {pickle_path.name}" in result.bad_records[0]["error"]
    assert pickle_path.stem in (tmp_path / "out" / ERRORS).read_text()


@pytest.mark.parametrize("content", [None, b"tokens: [a, b\n", b"\xff\xfe tokens", b"- just\n- a list\n"])
def test_navsim_scene_filter_missing_or_unreadable_is_one_line(raw, tmp_path, capsys, content):
    scene_filter = tmp_path / "filter.yaml"
    if content is not None:
        scene_filter.write_bytes(content)
    argv = ["convert", "navsim", "--src", str(raw["navsim"]), "--out", str(tmp_path / "out"), "--quiet"]
    line = user_error([*argv, "--scene-filter", str(scene_filter)], capsys)
    assert str(scene_filter) in line
    assert not (tmp_path / "out").exists()


def test_inspect_checks_every_sample_unless_quick(tmp_path, capsys):
    write_toy_logs(tmp_path / "src", n_logs=5, frames=8)  # 40 samples: more than the old 32 checked
    convert(ToyAdapter(), tmp_path / "src", tmp_path / "data", shard_size=8)
    assert inspect_dataset(tmp_path / "data")["checked"] == 40
    assert inspect_dataset(tmp_path / "data", quick=5)["checked"] == 5
    from lead_s2r import cli

    assert cli.main(["inspect", str(tmp_path / "data"), "--quick", "--n", "3", "--no-progress"]) == 0
    assert json.loads(capsys.readouterr().out)["checked"] == 3


# --------------------------------------------------------------------------- crash


def test_laz_that_aborts_the_decoder_fails_one_log(raw, tmp_path):
    src = copy_of(raw["carla_lead"], tmp_path)
    first, second = routes(src)
    rewrite(first / "lidar" / "0001.laz", aborting_laz((first / "lidar" / "0001.laz").read_bytes()))
    result = convert(get_adapter("carla_lead"), src, tmp_path / "out")
    assert [error["log"] for error in result.errors] == [f"{first.parent.name}/{first.name}"]
    assert f"{first / 'lidar' / '0001.laz'}: corrupt LAZ file (the LAZ decoder died on it" in result.errors[0]["error"]
    assert logs_of(tmp_path / "out") == {f"{second.parent.name}/{second.name}"}
    assert result.samples == 3  # the other route, whole


# --------------------------------------------------------------------------- tracebacks


@pytest.mark.parametrize("content", [b'{"a": "\xff"}', b'{"a": ', b'["not", "a", "mapping"]', b'{"a": {"x": 1}}'])
def test_wod_cluster_json_corrupt_is_one_line(raw, tmp_path, capsys, content):
    src = copy_of(raw["wod_e2e"], tmp_path)
    rewrite(src / CLUSTERS, content)
    line = user_error(["convert", "wod_e2e", "--src", str(src), "--out", str(tmp_path / "out"), "--quiet"], capsys)
    assert str(src / CLUSTERS) in line


@pytest.mark.parametrize(
    ("name", "content"),
    [
        (INFO, None),
        (INFO, b'{"adapter": '),
        (INFO, b"\xff\xfe"),
        (INFO, b"[1]"),
        (MANIFEST, None),
        (MANIFEST, b"PAR1 not parquet"),
        (MANIFEST, "truncated"),
    ],
)
def test_corrupt_or_missing_info_or_manifest_is_one_line(converted, tmp_path, capsys, name, content):
    folder = copy_of(converted["wod_e2e"], tmp_path)
    path = folder / name
    if content is None:
        path.unlink()
    else:
        rewrite(path, path.read_bytes()[:200] if content == "truncated" else content)
    line = user_error(["inspect", str(folder), "--no-progress"], capsys)
    assert str(folder) in line
    if name == MANIFEST:
        argv = ["score", "--metric", "ade", "--planner", "human", "--data", str(folder), "--out", str(tmp_path / "s")]
        assert str(folder) in user_error(argv, capsys)
        with pytest.raises(ShardError, match=str(path) if content is not None else str(folder)):
            list(read_samples(folder))


def test_folder_whose_conversion_failed_entirely(tmp_path, capsys):
    write_toy_logs(tmp_path / "src", n_logs=2, frames=4, broken=(0, 1))
    assert not convert(ToyAdapter(), tmp_path / "src", tmp_path / "data").ok
    line = user_error(["inspect", str(tmp_path / "data")], capsys)
    assert "lists no sample" in line
    with pytest.raises(ShardError, match="lists no sample"):
        list(read_samples(tmp_path / "data"))


def test_table_results_and_submission_errors_are_user_errors(converted, tmp_path, capsys):
    assert "table6: cannot read table spec" in user_error(
        ["table", "--spec", "table6", "--runs", str(tmp_path)], capsys
    )
    missing = tmp_path / "results.json"
    argv = ["carla-metrics", str(missing), "--benchmark", "longest6", "--out", str(tmp_path / "m")]
    assert f"{missing}: cannot read results JSON" in user_error(argv, capsys)
    samples = list(read_samples(converted["navsim"], fields=("future",)))
    predictions = write_predictions(tmp_path / "p.parquet", [predict_human(s) for s in samples[:3]])
    people = ["--team", "t", "--authors", "a", "--email", "e", "--institution", "i", "--country", "c"]
    argv = ["submit", "navsim", "--predictions", str(predictions), "--data", str(converted["navsim"])]
    line = user_error([*argv, "--out", str(tmp_path / "sub" / "submission.pkl"), *people], capsys)
    assert f"{predictions}: {len(samples) - 3} of {len(samples)} tokens have no prediction" in line
    assert not (tmp_path / "sub").exists()
    metadata = ["--account", "me@example.com", "--method", "m", "--authors", "a", "--num-params", "1M"]
    argv = ["submit", "wod-e2e", "--predictions", str(predictions), "--data", str(converted["wod_e2e"])]
    line = user_error([*argv, "--out", str(tmp_path / "wod"), *metadata, "--pretrained", "false"], capsys)
    assert "test" in line and not (tmp_path / "wod").exists()


def test_closed_stdout_ends_quietly():
    read_end, write_end = os.pipe()
    os.close(read_end)
    done = subprocess.run(
        [sys.executable, "-m", "lead_s2r.cli", "adapters"], stdout=write_end, stderr=subprocess.PIPE, check=False
    )
    os.close(write_end)
    assert done.returncode == 141 and done.stderr == b""


def test_adapter_error_names_the_file_not_the_code_line(raw, tmp_path):
    src = copy_of(raw["carla_lead"], tmp_path)
    boxes_path = routes(src)[0] / "bboxes" / "0001.pkl"
    with lzma.open(boxes_path, "rb") as file:
        boxes = restricted_pickle.load(file)
    box = next(i for i, b in enumerate(boxes) if b.get("class") != "ego_car")
    boxes[box]["extent"] = 7  # a number where LEAD writes three
    boxes_path.unlink()
    with lzma.open(boxes_path, "wb") as file:
        file.write(pickle.dumps(boxes))
    result = convert(get_adapter("carla_lead"), src, tmp_path / "out")
    (error,) = result.errors
    assert str(boxes_path) in error["error"] and "(at " not in error["error"]


# --------------------------------------------------------------------------- wrong inputs that "succeeded"


def test_predict_without_weights_refuses(tmp_path, toy_data, plain_argv, capsys):  # noqa: F811
    config = fit_config(tmp_path, {"carla": {"paths": [toy_data], "cameras": ["front"]}})
    line = user_error(["predict", "--config", str(config)], capsys)
    assert "no weights given; pass --ckpt_path" in line and "--untrained" in line
    assert not (tmp_path / "run").exists()


def test_convert_of_another_datasets_folder_is_an_error(raw, tmp_path, capsys):
    argv = ["convert", "carla_lead", "--src", str(raw["navsim"]), "--out", str(tmp_path / "out"), "--quiet"]
    assert "the carla_lead adapter finds no logs there" in user_error(argv, capsys)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("metric", "data"), [("rfs@wod-e2e-2025", "navsim"), ("pdms@navsim-1.1", "wod_e2e")])
def test_metric_on_data_it_is_not_defined_on(converted, tmp_path, capsys, metric, data):
    samples = list(read_samples(converted[data], fields=("future",)))
    predictions = write_predictions(tmp_path / "p.parquet", [predict_human(s, horizon=5.0) for s in samples])
    argv = ["score", "--metric", metric, "--predictions", str(predictions), "--data", str(converted[data])]
    line = user_error([*argv, "--out", str(tmp_path / "scores")], capsys)
    assert f"--metric {metric} scores" in line and f"holds datasets ['{data}']" in line
    assert not (tmp_path / "scores").exists()


def test_inspect_png_in_a_missing_folder(toy_data, tmp_path, capsys):
    line = user_error(["inspect", toy_data, "--png", str(tmp_path / "nodir" / "x.png")], capsys)
    assert f"folder {tmp_path / 'nodir'} does not exist" in line
    assert "ending in .png" in user_error(["inspect", toy_data, "--png", str(tmp_path / "x.gif")], capsys)


def test_score_planner_failure_leaves_nothing_behind(converted, tmp_path, capsys):
    out = tmp_path / "scores"
    # the planner writes its predictions into --out first; RFS then finds no rated sample in NAVSIM data
    argv = ["score", "--metric", "rfs@wod-e2e-2025", "--planner", "human", "--data", str(converted["navsim"])]
    argv += ["--out", str(out)]
    assert "samples with ['raters']" in user_error(argv, capsys)
    assert not out.exists()
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    user_error(argv, capsys)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]  # what was there stays, what the run wrote goes


def test_fuzz_trials_helpers_make_real_corruptions(tmp_path):
    """The corruptions change the file (or delete it) for every kind, so a fuzz trial tests something."""
    from corruptions import KINDS, corrupt

    rng = np.random.default_rng(0)
    for kind in KINDS:
        path = tmp_path / f"{kind}.json"
        original = json.dumps({"a": [1, 2, {"b": "c"}]}).encode()
        path.write_bytes(original)
        corrupt(path, kind, rng)
        assert not path.exists() or path.read_bytes() != original
    path = tmp_path / "filter.yaml"
    path.write_text(yaml.safe_dump({"tokens": ["a", "b"]}))
    corrupt(path, "wrong_type", rng)
    assert yaml.safe_load(path.read_text()) != {"tokens": ["a", "b"]}


def test_navsim_damaged_map_names_the_geopackage(raw, tmp_path):
    src = copy_of(raw["navsim"], tmp_path)
    (gpkg,) = (src / "maps").rglob("map.gpkg")
    rewrite(gpkg, gpkg.read_bytes()[: gpkg.stat().st_size // 2])
    from lead_s2r_adapters import navsim_map

    navsim_map.load_map.cache_clear()  # a map read by an earlier test in this process
    result = convert(get_adapter("navsim", maps=str(src / "maps")), src, tmp_path / "out")
    assert len(result.errors) == 2
    assert all(f"{gpkg}: not a readable GeoPackage" in error["error"] for error in result.errors)


def test_navsim_map_damaged_inside_a_layer_names_the_geopackage(tmp_path):
    """The fuzz's damage (seed 5307, trial 11 of the navsim target: 211 bytes at 101790 of the synthetic map)
    leaves SQLite opening the file and fails while a layer's rows stream ("database disk image is malformed"), which
    once ended without the file's name."""
    from lead_s2r.synthetic import navsim
    from lead_s2r_adapters import navsim_map

    navsim.generate(tmp_path / "raw", count=2, seed=3)  # the fuzz's map
    (gpkg,) = (tmp_path / "raw" / "maps").rglob("map.gpkg")
    data, span = bytearray(gpkg.read_bytes()), (DATA / "navsim_map_fuzz5307_span.bin").read_bytes()
    data[101790 : 101790 + len(span)] = span
    gpkg.write_bytes(bytes(data))
    with pytest.raises(navsim_map.MapError, match=f"^{re.escape(str(gpkg))}: not a readable GeoPackage"):
        navsim_map.load_map(tmp_path / "raw" / "maps", "us-nv-las-vegas-strip")


class _NaNBoxesAdapter(ToyAdapter):
    """A toy adapter that passes a raw value it did not check into a sample (NaN in the boxes of its first log)."""

    def iter_samples(self, log):
        for sample in super().iter_samples(log):
            if log.log_id.endswith("000"):
                sample["boxes"][0, 0] = np.nan
            yield sample


def test_schema_error_of_a_converted_sample_names_the_source(tmp_path):
    write_toy_logs(tmp_path / "src", n_logs=2, frames=3)
    result = convert(_NaNBoxesAdapter(), tmp_path / "src", tmp_path / "out")
    (error,) = result.errors
    assert error["error"].startswith(f"SchemaError: {tmp_path / 'src' / 'log000.json'}: sample ")
    assert "field 'boxes': contains NaN" in error["error"] and result.samples == 3


def test_manifest_with_invalid_utf8_is_a_shard_error(converted, tmp_path):
    folder = copy_of(converted["wod_e2e"], tmp_path)
    table = load_manifest(folder)
    keys = pa.array([b"\xf6" + key.encode() for key in table["key"].to_pylist()], pa.binary()).view(pa.string())
    (folder / MANIFEST).unlink()
    pq.write_table(table.set_column(table.column_names.index("key"), "key", keys), folder / MANIFEST)
    with pytest.raises(ShardError, match=f"{folder / MANIFEST}: cannot be read as a manifest"):
        list(read_samples(folder))


def test_navsim_wrong_typed_log_value_names_the_log_file(raw, tmp_path):
    src = copy_of(raw["navsim"], tmp_path)
    log = sorted((src / "navsim_logs" / "mini").glob("*.pkl"))[0]
    with open(log, "rb") as file:
        frames = restricted_pickle.load(file)
    for frame in frames:
        frame["lidar2ego_translation"] = ["a", 0.0, 1.8]  # a string where metres go
    rewrite(log, pickle.dumps(frames))
    (error,) = convert(get_adapter("navsim"), src, tmp_path / "out").errors
    assert error["error"].startswith(f"NavsimFormatError: {log} frame ")
    assert "a value of an unexpected type (ValueError" in error["error"]


@pytest.mark.parametrize(
    ("location", "expected"),
    [(True, "field 'map_location' is bool, not str"), ("us-xx-nowhere", "no map for location 'us-xx-nowhere'")],
)
def test_navsim_log_map_location_without_a_map_names_the_log_file(raw, tmp_path, location, expected):
    """Found by the fuzz (seed 7411): a location of another type was read as the text 'True', and a location the maps
    folder lacks named only the missing map; both are the log's values, so the error names the log's pickle."""
    src = copy_of(raw["navsim"], tmp_path)
    log = sorted((src / "navsim_logs" / "mini").glob("*.pkl"))[0]
    with open(log, "rb") as file:
        frames = restricted_pickle.load(file)
    for frame in frames:
        frame["map_location"] = location
    rewrite(log, pickle.dumps(frames))
    (error,) = convert(get_adapter("navsim", maps=str(src / "maps")), src, tmp_path / "out").errors
    assert error["error"].startswith(f"NavsimFormatError: {log} frame ") or error["error"].startswith(
        f"MapError: {log} frame "
    )
    assert expected in error["error"]


def test_lead_box_value_that_is_no_number_names_the_boxes_file(raw, tmp_path):
    """Found by the fuzz (seed 8123): a None in a box's position read as NaN, and only the sample check caught it,
    naming the route but not the file."""
    src = copy_of(raw["carla_lead"], tmp_path)
    first, _ = routes(src)
    path = first / "bboxes" / "0001.pkl"
    with lzma.open(path, "rb") as file:
        boxes = restricted_pickle.load(file)
    other = next(i for i, box in enumerate(boxes) if box.get("class") != "ego_car")
    boxes[other]["position"] = [boxes[other]["position"][0], None, boxes[other]["position"][2]]
    path.unlink()
    with lzma.open(path, "wb") as file:
        pickle.dump(boxes, file)
    (error,) = convert(get_adapter("carla_lead"), src, tmp_path / "out").errors
    assert f"{path}: box " in error["error"] and "must be finite numbers" in error["error"]


def test_converted_camera_matrix_of_ragged_rows_is_a_schema_error(converted, tmp_path, capsys):
    """Found by the fuzz (seed 8123): a ragged K in a converted sample's meta was numpy's ValueError in inspect."""
    sample = next(iter(read_samples(converted["wod_e2e"])))
    sample["meta"]["cameras"][0]["K"] = [[1.0, 0.0, 2.0], [0.0, 1.0], [0.0, 0.0, 1.0]]
    with pytest.raises(SchemaError, match=r"meta.cameras\[0\]'?: K must be 3x3 and cam_to_ego 4x4 finite numbers"):
        validate(sample)


def test_human_planner_on_a_damaged_future_names_the_data_folder(converted, tmp_path, capsys):
    """Found by the fuzz (seed 9029): a flipped bit in a converted future's t was blamed on the prediction."""
    folder = copy_of(converted["navsim"], tmp_path)
    tar = sorted((folder / "shards").glob("*.tar"))[0]
    data = bytearray(tar.read_bytes())
    with tarfile.open(tar) as archive:
        member = next(m for m in archive.getmembers() if m.name.endswith(".future.npy"))
    future = np.load(io.BytesIO(bytes(data[member.offset_data : member.offset_data + member.size])))
    start = member.offset_data + member.size - future.nbytes + 2 * future.shape[1] * 4  # row 2's t
    data[start : start + 4] = np.float32(future[0, 0]).tobytes()  # earlier than row 1's
    rewrite(tar, bytes(data))
    args = ["score", "--metric", "ade", "--planner", "human", "--data", str(folder), "--out", str(tmp_path / "s")]
    message = user_error(args, capsys)
    assert message.startswith(f"error: {folder}: sample '{member.name.split('.')[0]}', field 'future': t must be")
    assert not (tmp_path / "s").exists()


def test_laz_header_claiming_too_many_points_or_a_stuck_decoder_is_refused(raw, tmp_path, monkeypatch):
    """A damaged point count made the decoder fill gigabytes for minutes (a hang of the whole conversion)."""
    from lead_s2r_adapters import laz_decoder
    from lead_s2r_adapters.carla_lead_io import LeadFormatError, read_laz

    laz = routes(copy_of(raw["carla_lead"], tmp_path))[0] / "lidar" / "0001.laz"
    data = bytearray(laz.read_bytes())
    struct.pack_into("<I", data, 107, 2_000_000_000)  # LAS 1.2 header: number of point records
    rewrite(laz, bytes(data))
    with pytest.raises(LeadFormatError, match=f"{laz}: corrupt LAZ file .*the header claims 2000000000 points"):
        read_laz(laz)
    monkeypatch.setattr(laz_decoder._Helper, "process", None)  # a fresh helper: it cannot answer within 0 s
    monkeypatch.setattr(laz_decoder, "TIMEOUT_S", 0.0)
    with pytest.raises(LeadFormatError, match="the LAZ decoder took over 0 s on it and was stopped"):
        read_laz(laz)
