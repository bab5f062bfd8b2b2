"""What ``lead-s2r report`` reads of a run, damaged: each damage is a UserError naming the file, never a traceback
or a report of other numbers."""

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from corruptions import flip_footer_byte, flip_in_value

from lead_s2r.errors import UserError
from lead_s2r.predictions import Prediction, write_predictions
from lead_s2r.report.run_outputs import load_run
from lead_s2r.scoring.scores_file import ScoresFile

T = 0.5 * np.arange(1, 9)
LOG = "epoch,step,train/loss\n0,1,2.5\n0,2,1.5\n"


def scored_run(root: Path, report: dict[str, Any] | None = None) -> Path:
    """A run as `lead-s2r score` leaves it: ADE of two samples (the first 1234.5 m off), its predictions, a log."""
    run = root / "run"
    predictions = [Prediction(key, "navsim", T, np.column_stack([T, 0 * T]), 0 * T) for key in ("k0", "k1")]
    write_predictions(root / "predictions.parquet", predictions)
    rows = pa.table({"key": ["k0", "k1"], "dataset": ["navsim"] * 2, "ade": [1234.5, 2.0]})
    defaults = {"metric": "ade", "predictions": str(root / "predictions.parquet"), "data": [], "tag": None}
    ScoresFile(run / "ade", defaults | {"config": {}, "aggregates": {"ade": 618.25}} | (report or {}), rows).write()
    (run / "logs").mkdir()
    (run / "logs" / "metrics.csv").write_text(LOG)
    (run / "logs" / "config.yaml").write_text("seed_everything: 0\n")
    return run


def test_the_run_reads_whole(tmp_path: Path) -> None:
    run = load_run(scored_run(tmp_path))
    assert run.scores[0].headline("k0") == 1234.5 and sorted(run.predictions) == ["k0", "k1"]
    assert run.logs == {"train/loss": [(1.0, 2.5), (2.0, 1.5)]} and run.config == "seed_everything: 0\n"


def test_a_flipped_score_fails_its_page_checksum(tmp_path: Path) -> None:
    """Without the CRC ScoresFile.write stores, the report would show 1234.5000000000002 for k0."""
    run = scored_run(tmp_path)
    flip_in_value(run / "ade" / "scores.parquet", np.float64(1234.5).tobytes())
    with pytest.raises(UserError, match=r"ade: cannot read scores\.json / scores\.parquet .*(CRC|checksum)"):
        load_run(run)


def test_a_column_renamed_in_the_scores_footer_is_named(tmp_path: Path) -> None:
    """The footer's names carry no checksum: 'ade' renamed by a flip read as a metric without its headline."""
    table = scored_run(tmp_path) / "ade" / "scores.parquet"
    flip_footer_byte(table, lambda path: "ade" not in pq.read_schema(path).names)
    with pytest.raises(UserError, match=r"ade: cannot read scores\.json / scores\.parquet .*footer names the columns"):
        load_run(tmp_path / "run")


def test_a_truncated_scores_table_is_named(tmp_path: Path) -> None:
    """pyarrow's ArrowInvalid ("magic bytes not found") was a traceback."""
    table = scored_run(tmp_path) / "ade" / "scores.parquet"
    table.write_bytes(table.read_bytes()[:100])
    with pytest.raises(UserError, match=r"ade: cannot read scores\.json / scores\.parquet .*magic bytes"):
        load_run(tmp_path / "run")


@pytest.mark.parametrize(
    ("field", "value"),
    [("data", 7), ("data", [7]), ("tag", 7), ("predictions", None), ("config", {"reference_cache": 7})],
)
def test_a_wrong_typed_scores_json_field_is_named(tmp_path: Path, field: str, value: Any) -> None:
    """Each was a TypeError or AttributeError where the report used the field."""
    with pytest.raises(UserError, match=rf"ade/scores\.json: .*{field[:6]}.* is "):
        load_run(scored_run(tmp_path, {field: value}))


def test_scores_json_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    run = scored_run(tmp_path)
    (run / "ade" / "scores.json").write_bytes(b'{"metric": "\xff"}')
    with pytest.raises(UserError, match=r"ade: cannot read scores\.json .*'utf-8' codec"):
        load_run(run)


def test_a_scores_table_keyed_by_numbers_is_named(tmp_path: Path) -> None:
    run = scored_run(tmp_path)
    report = json.loads((run / "ade/scores.json").read_text())
    ScoresFile(run / "ade", report, pa.table({"key": [0, 1], "ade": [1.0, 2.0]})).write()
    with pytest.raises(UserError, match=r"scores\.parquet: its key column holds int64"):
        load_run(run)


@pytest.mark.parametrize(
    ("log", "message"),
    [
        (b"epoch,step,train/loss\n0,1,2.5\x00\n", "could not convert string to float"),  # was a ValueError traceback
        (b"epoch,step,train/loss\n0,1,2.5,7\n", "line 2 has more cells than the header"),  # was a TypeError
        (b"epoch,step,train/loss\n0,1,\xff\n", "'utf-8' codec"),  # was a UnicodeDecodeError traceback
        (b"epoch,spep,train/loss\n0,1,2.5\n", "no step column"),  # was a log without curves
    ],
)
def test_a_damaged_training_log_is_named(tmp_path: Path, log: bytes, message: str) -> None:
    run = scored_run(tmp_path)
    (run / "logs" / "metrics.csv").write_bytes(log)
    with pytest.raises(UserError, match=rf"metrics\.csv: not a Lightning CSV log \(.*{message}"):
        load_run(run)


def test_a_saved_config_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    run = scored_run(tmp_path)
    (run / "logs" / "config.yaml").write_bytes(b"seed_everything: \xff\n")
    with pytest.raises(UserError, match=r"config\.yaml: not UTF-8 text"):
        load_run(run)
