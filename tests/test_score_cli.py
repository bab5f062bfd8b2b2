"""score_predictions end to end: converted shards + predictions.parquet -> scores.parquet / scores.json."""

import json
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from corruptions import flip_footer_byte, flip_in_value

from lead_s2r import __version__, cli
from lead_s2r.predictions import Prediction, PredictionError, read_predictions, write_predictions
from lead_s2r.schema import SCHEMA_VERSION, validate
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import SHARD_DIR, ShardFile
from lead_s2r.training.scoring_callback import ScoringCallback

GRID = np.arange(1, 21) * 0.25  # WOD-E2E 4 Hz x 5 s


def straight(speed: float, t: np.ndarray = GRID, lateral: float = 0.0) -> np.ndarray:
    """(T, 2) constant-velocity drive along +x, shifted ``lateral`` metres to the left."""
    return np.stack([speed * t, np.full_like(t, lateral)], axis=-1)


def scoring_sample(
    key: str,
    dataset: str = "wod_e2e",
    speed: float = 10.0,
    raters: list[tuple[np.ndarray, float]] | None = None,
    future: np.ndarray | None = None,
    cluster: str | None = None,
) -> dict[str, Any]:
    """A schema-valid sample with what scorers read: ego speed, optional raters, future and WOD cluster."""
    extras = {"wod_e2e": {"cluster": cluster}} if cluster else {}
    meta = {
        "schema_version": SCHEMA_VERSION,
        "dataset": dataset,
        "split": "val",
        "log_id": key.rsplit("_", 1)[0],
        "frame_idx": 0,
        "timestamp_us": 0,
        "is_synthetic": False,
        "adapter": dataset,
        "adapter_version": "test",
        "ego": {
            "speed": speed,
            "velocity": [speed, 0.0],
            "acceleration": [0.0, 0.0],
            "yaw_rate": 0.0,
            "command": 2,
            "command_raw": 1,
        },
        "vehicle": {"length": 4.8, "width": 2.0, "wheel_base": 2.9, "rear_axle_to_center": 1.4},
        "cameras": [],
        "has": {},
        "extras": extras,
    }
    sample = {"__key__": key, "meta": meta, "past": np.zeros((1, 4), np.float32)}
    if raters:
        longest = max(len(trajectory) for trajectory, _ in raters)
        padded = np.full((len(raters), longest, 2), np.nan, np.float32)
        for p, (trajectory, _) in enumerate(raters):
            padded[p, : len(trajectory)] = trajectory
        sample["raters"] = {
            "trajectories": padded,
            "scores": np.array([label for _, label in raters], np.float32),
            "lengths": np.array([len(trajectory) for trajectory, _ in raters], np.int32),
        }
    if future is not None:
        sample["future"] = future.astype(np.float32)
    meta["has"] = {name: True for name in ("raters", "future") if name in sample}
    validate(sample)
    return sample


def prediction(key: str, xy: np.ndarray, t: np.ndarray = GRID, dataset: str = "wod_e2e", **kw: Any) -> Prediction:
    return Prediction(key, dataset, t.astype(np.float32), xy.astype(np.float32), np.zeros(len(t), np.float32), **kw)


def write_converted(folder: Path, samples: list[dict[str, Any]]) -> Path:
    (folder / SHARD_DIR).mkdir(parents=True)
    shard = ShardFile(folder / SHARD_DIR / "test-000000.tar")
    for sample in samples:
        shard.write(sample)
    shard.close()
    return folder


@pytest.fixture
def wod_folder(tmp_path: Path) -> Path:
    """Three rated WOD frames in two clusters and one frame without ratings."""
    samples = [
        scoring_sample("seg_a", raters=[(straight(10), 10.0), (straight(10, lateral=3), 6.0)], cluster="Cyclist"),
        scoring_sample(
            "seg_b", raters=[(straight(10), 8.0)], cluster="Cyclist", future=np.c_[GRID, straight(10), 0 * GRID]
        ),
        scoring_sample("seg_c", raters=[(straight(5), 9.0)], cluster="Construction"),
        scoring_sample("seg_d", future=np.c_[GRID, straight(10), 0 * GRID]),
    ]
    return write_converted(tmp_path / "wod", samples)


def test_rfs_scores_files_and_reports(wod_folder: Path, tmp_path: Path) -> None:
    predictions = [
        prediction("seg_a", straight(10)),  # on rater 1 -> 10
        prediction("seg_b", straight(10, lateral=3)),  # 3 m off the only rater at 10 m/s -> floor 4
        prediction("seg_c", straight(5)),  # on the rater -> 9
        prediction("seg_d", straight(10)),  # no rating: skipped
    ]
    path = write_predictions(tmp_path / "predictions.parquet", predictions)
    report = score_predictions("rfs@wod-e2e-2025", path, wod_folder, tmp_path / "out")
    assert report == json.loads((tmp_path / "out" / "scores.json").read_text())
    table = pq.read_table(tmp_path / "out" / "scores.parquet").to_pydict()
    assert table["key"] == ["seg_a", "seg_b", "seg_c"]
    np.testing.assert_allclose(table["rfs"], [10.0, 4.0, 9.0], atol=1e-12)
    assert table["fully_within"] == [True, False, True]
    assert table["cluster"] == ["Cyclist", "Cyclist", "Construction"]
    aggregates = report["aggregates"]
    assert aggregates["rfs"] == pytest.approx(23 / 3, abs=1e-12)
    assert aggregates["rfs_cluster_macro"] == pytest.approx((7.0 + 9.0) / 2, abs=1e-12)
    assert aggregates["rfs_per_cluster"] == pytest.approx({"Construction": 9.0, "Cyclist": 7.0})
    assert (aggregates["frames"], aggregates["frames_scored"], aggregates["frames_skipped_no_rating"]) == (4, 3, 1)
    assert report["metric"] == "rfs@wod-e2e-2025" and report["package_version"] == __version__
    assert report["config"]["floor"] == 4.0 and report["config"]["decay"] == 0.1


def test_config_reaches_the_scorer(wod_folder: Path, tmp_path: Path) -> None:
    predictions = [prediction(k, straight(10, lateral=3)) for k in ("seg_a", "seg_b", "seg_c", "seg_d")]
    path = write_predictions(tmp_path / "p.parquet", predictions)
    floored = score_predictions("rfs@wod-e2e-2025", path, wod_folder, tmp_path / "a")
    unfloored = score_predictions("rfs@wod-e2e-2025", path, wod_folder, tmp_path / "b", floor=0.0)
    table = pq.read_table(tmp_path / "b" / "scores.parquet").to_pydict()
    assert floored["aggregates"]["rfs"] > unfloored["aggregates"]["rfs"]
    assert table["rfs"][0] == pytest.approx(6.0, abs=1e-12)  # inside rater 2's box (label 6)
    assert unfloored["config"]["floor"] == 0.0


def test_score_verb(wod_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    keys = ("seg_a", "seg_b", "seg_c", "seg_d")
    path = write_predictions(tmp_path / "p.parquet", [prediction(k, straight(10, lateral=3)) for k in keys])
    argv = ["score", "--metric", "rfs@wod-e2e-2025", "--predictions", str(path), "--data", str(wod_folder)]
    assert cli.main([*argv, "--out", str(tmp_path / "out"), "--option", "floor=0", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((tmp_path / "out" / "scores.json").read_text())
    assert printed["config"]["floor"] == 0 and printed["aggregates"]["frames_scored"] == 3


def test_score_verb_takes_its_dataset_from_a_mixed_file_and_lists_the_unpredicted(
    wod_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    navsim_t = np.arange(1, 9) * 0.5
    predictions = [prediction(k, straight(10)) for k in ("seg_a", "seg_b", "seg_c")]  # seg_d has none
    predictions.append(prediction("log_0", straight(8, navsim_t), t=navsim_t, dataset="navsim"))
    path = write_predictions(tmp_path / "p.parquet", predictions)
    argv = ["score", "--metric", "rfs@wod-e2e-2025", "--predictions", str(path), "--data", str(wod_folder)]
    assert cli.main([*argv, "--out", str(tmp_path / "out"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((tmp_path / "out" / "scores.json").read_text())
    assert printed["unpredicted"] == {"count": 1, "keys": ["seg_d"]}
    assert printed["other_datasets"] == {"navsim": 1}
    # seg_a and seg_b drive on a rater (10 and 8), seg_c at 10 m/s against a 5 m/s rater is floored to 4
    assert printed["aggregates"]["rfs"] == pytest.approx((10 + 8 + 4) / 3, abs=1e-12)
    assert cli.main([*argv, "--out", str(tmp_path / "strict"), "--strict"]) == 2
    assert "sample 'seg_d' has no prediction (1 such sample(s))" in capsys.readouterr().err
    assert not (tmp_path / "strict").exists()


def test_score_verb_prints_a_short_table_with_the_headline_and_frame_counts(
    wod_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_predictions(tmp_path / "p.parquet", [prediction(k, straight(10)) for k in ("seg_a", "seg_b", "seg_c")])
    argv = ["score", "--metric", "rfs@wod-e2e-2025", "--predictions", str(path), "--data", str(wod_folder)]
    assert cli.main([*argv, "--out", str(tmp_path / "out"), "--split", "val"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) <= 30
    rows = {cells[0]: cells[1] for cells in (line.strip("│ ").split("│") for line in lines) if len(cells) == 2}
    rows = {label.strip(): value.strip() for label, value in rows.items()}
    assert rows["rfs"] == f"{(10 + 8 + 4) / 3:.4f}" and rows["frames scored"] == "3"
    assert rows["frames skipped no rating"] == "0" and rows["frames without a prediction (left out)"] == "1"
    assert lines[-1].startswith(f"wrote {tmp_path / 'out' / 'scores.json'} and scores.parquet")


def test_score_split_names_the_splits_held_and_the_human_planner_skips_frames_without_a_future(
    wod_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["score", "--metric", "ade", "--planner", "human", "--data", str(wod_folder)]
    assert cli.main([*argv, "--out", str(tmp_path / "test"), "--split", "test"]) == 2
    assert f"--split test: {wod_folder} holds no such split; it holds ['val']" in capsys.readouterr().err
    assert cli.main([*argv, "--out", str(tmp_path / "out"), "--split", "val", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["split"] == "val" and printed["unpredicted"] == {"count": 2, "keys": ["seg_a", "seg_c"]}
    assert printed["aggregates"]["ade"] == 0.0 and printed["aggregates"]["frames"] == 2


def test_ade_scores_files_per_dataset(wod_folder: Path, tmp_path: Path) -> None:
    navsim_t = np.arange(1, 9) * 0.5
    navsim = write_converted(
        tmp_path / "navsim",
        [scoring_sample("log_0", dataset="navsim", future=np.c_[navsim_t, straight(8, navsim_t), 0 * navsim_t])],
    )
    predictions = [prediction(k, straight(10, lateral=1)) for k in ("seg_a", "seg_b", "seg_c", "seg_d")]
    predictions.append(prediction("log_0", straight(8, navsim_t) + np.array([3.0, 4.0]), t=navsim_t, dataset="navsim"))
    path = write_predictions(tmp_path / "p.parquet", predictions)
    report = score_predictions("ade", path, [wod_folder, navsim], tmp_path / "out")
    per_dataset = report["aggregates"]["per_dataset"]
    assert per_dataset["navsim"]["ade"] == pytest.approx(5.0, abs=1e-6)
    assert per_dataset["navsim"]["ade_3s"] is None
    assert per_dataset["wod_e2e"]["ade"] == pytest.approx(1.0, abs=1e-6)
    assert per_dataset["wod_e2e"]["frames"] == 4 and per_dataset["wod_e2e"]["frames_rated"] == 3
    table = pq.read_table(tmp_path / "out" / "scores.parquet").to_pydict()
    assert table["key"] == ["seg_a", "seg_b", "seg_c", "seg_d", "log_0"]


def test_predictions_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    written = [
        prediction(f"k{i}", rng.normal(size=(20, 2)), probability=p, inference=j)
        for i in range(3)
        for j, p in enumerate((0.7, 0.3))
    ]
    read = read_predictions(write_predictions(tmp_path / "p.parquet", written))
    for a, b in zip(written, read, strict=True):
        assert (a.key, a.dataset, a.probability, a.inference) == (b.key, b.dataset, b.probability, b.inference)
        assert a.t.tobytes() == b.t.tobytes() and a.xy.tobytes() == b.xy.tobytes()


def test_a_flipped_coordinate_fails_its_page_checksum(tmp_path: Path) -> None:
    """Without the CRC write_predictions stores, the file would read back with x[3] = 1234.5001."""
    xy = np.column_stack([np.where(np.arange(20) == 3, 1234.5, 1.0), np.zeros(20)])
    path = write_predictions(tmp_path / "p.parquet", [prediction("k0", xy)])
    flip_in_value(path, np.float32(1234.5).tobytes())
    with pytest.raises(PredictionError, match=r"p\.parquet: not a readable parquet file.*(CRC|checksum)"):
        read_predictions(path)


def test_a_flipped_row_count_or_column_name_in_the_footer_is_named(tmp_path: Path) -> None:
    """No checksum covers the footer: a row group's count cut by a flip read 1 of 2 predictions, a renamed 'inference'
    column read as absent, both without a word (a single inference per key needs neither column)."""
    rows = [prediction(f"k{i}", np.zeros((20, 2)), inference=1) for i in range(2)]
    path = write_predictions(tmp_path / "p.parquet", rows)
    flip_footer_byte(path, lambda p: pq.read_metadata(p).num_rows == 2 != pq.read_metadata(p).row_group(0).num_rows)
    with pytest.raises(PredictionError, match=r"p\.parquet: .*footer counts 2 rows, its row groups \d"):
        read_predictions(path)
    path = write_predictions(tmp_path / "p.parquet", rows)
    flip_footer_byte(path, lambda p: "inference" not in pq.read_schema(p).names)
    with pytest.raises(PredictionError, match=r"p\.parquet: .*footer names the columns .*written as .*'inference'"):
        read_predictions(path)


def _raw_table(path: Path, **columns: list[Any]) -> Path:
    base = {"key": ["k0"], "dataset": ["wod_e2e"], "t": [GRID.tolist()], "x": [[0.0] * 20], "y": [[0.0] * 20]}
    base["yaw"] = [[0.0] * 20]
    pq.write_table(pa.table({**base, **columns}), path)
    return path


@pytest.mark.parametrize(
    ("columns", "message"),
    [
        ({"x": [[float("nan")] * 20]}, "'k0'.*finite"),
        ({"y": [[0.0] * 19]}, "'k0'.*ragged"),
        ({"key": [None]}, "row 0 has a missing key"),
        ({"t": [(-GRID).tolist()]}, "'k0'.*t must be > 0"),
        ({"key": ["k0", "k0"], "dataset": ["a"] * 2, "t": [GRID.tolist()] * 2, "x": [[0.0] * 20] * 2,
          "y": [[0.0] * 20] * 2, "yaw": [[0.0] * 20] * 2, "inference": [0, 1]}, "several inferences for 'k0'"),
        ({"key": ["k0", "k0"], "dataset": ["a"] * 2, "t": [GRID.tolist()] * 2, "x": [[0.0] * 20] * 2,
          "y": [[0.0] * 20] * 2, "yaw": [[0.0] * 20] * 2}, "'k0': inference 0 appears twice"),
    ],
)  # fmt: skip
def test_bad_predictions_name_the_key(tmp_path: Path, columns: dict[str, list[Any]], message: str) -> None:
    with pytest.raises(PredictionError, match=message):
        read_predictions(_raw_table(tmp_path / "p.parquet", **columns))


def test_bad_joins_name_the_frame(wod_folder: Path, tmp_path: Path) -> None:
    keys = ("seg_a", "seg_b", "seg_c", "seg_d")
    cases = {
        "unknown": ([prediction(k, straight(10)) for k in (*keys, "seg_zz")], "'seg_zz' has no sample"),
        "missing": ([prediction(k, straight(10)) for k in keys[:3]], "'seg_d' has no prediction"),
        "horizon": (
            [prediction(k, straight(10)[:-1], t=GRID[:-1]) for k in keys],
            "'seg_a'.*horizon 4.75 s ends before the scored 5 s",
        ),
        "dataset": ([prediction(k, straight(10), dataset="navsim") for k in keys], "'seg_a': dataset 'navsim'"),
        "dataset_of_a_later_inference": (
            [prediction(k, straight(10)) for k in keys]
            + [prediction("seg_b", straight(10), dataset="navsim", probability=0.0, inference=1)],
            "'seg_b': dataset 'navsim'",
        ),
    }
    for name, (predictions, message) in cases.items():
        path = write_predictions(tmp_path / f"{name}.parquet", predictions)
        with pytest.raises(PredictionError, match=message):
            score_predictions("rfs@wod-e2e-2025", path, wod_folder, tmp_path / name)
    path = write_predictions(tmp_path / "subset.parquet", cases["missing"][0])
    report = score_predictions("rfs@wod-e2e-2025", path, wod_folder, tmp_path / "subset", allow_missing=True)
    assert report["aggregates"]["frames_scored"] == 3


class _Planner(L.LightningModule):
    """Predicts the 10 m/s straight line for every key, on a 2 Hz grid (resampled by the scorer)."""

    def __init__(self, keys: list[str]) -> None:
        super().__init__()
        self.keys = keys
        self.weight = torch.nn.Parameter(torch.zeros(1))

    def validation_step(self, batch: torch.Tensor, batch_idx: int) -> dict[str, Any]:
        t = np.arange(1, 11) * 0.5
        return {"predictions": [prediction(self.keys[int(i)], straight(10, t), t=t) for i in batch]}

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_callback_logs_rfs_and_ade_per_dataset(wod_folder: Path) -> None:
    keys = ["seg_a", "seg_b", "seg_c", "seg_d"]
    callback = ScoringCallback(wod_folder)
    trainer = L.Trainer(
        accelerator="cpu", callbacks=[callback], logger=False, enable_progress_bar=False, enable_model_summary=False
    )
    loader = torch.utils.data.DataLoader(torch.arange(len(keys)), batch_size=3)
    metrics = trainer.validate(_Planner(keys), loader, verbose=False)[0]
    # seg_a on rater 1 (10), seg_b on its rater (8), seg_c at 10 m/s vs a 5 m/s rater: 25 m short at 5 s -> floor 4
    assert metrics["val/wod_e2e/rfs"] == pytest.approx((10 + 8 + 4) / 3, abs=1e-6)
    assert metrics["val/wod_e2e/ade"] == pytest.approx(0.0, abs=1e-6)
    assert metrics["val/wod_e2e/ade_5s"] > 0


def test_callback_drops_repeated_predictions(wod_folder: Path) -> None:
    """A distributed sampler pads the last batches with samples it already gave out: each counts once."""
    callback = ScoringCallback(wod_folder)
    keys = ["seg_a", "seg_b", "seg_c", "seg_d"]
    predictions = [prediction(k, straight(10)) for k in keys]
    repeated = [*predictions, prediction("seg_b", straight(10, lateral=3)), prediction("seg_a", straight(5))]
    assert callback.compute(repeated) == callback.compute(predictions)
    assert callback.compute(predictions)["val/wod_e2e/rfs"] == pytest.approx((10 + 8 + 4) / 3, abs=1e-6)
