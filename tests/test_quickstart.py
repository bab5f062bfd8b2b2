"""The README's main job, end to end: every stage must leave real, consistent files behind."""

import io
import json

import pyarrow.parquet as pq
from rich.console import Console

from lead_s2r.predictions import read_predictions
from lead_s2r.quickstart import BASELINE, METRICS, MODEL, quickstart
from lead_s2r.shards import load_manifest


def test_quickstart_runs_every_stage(tmp_path, capsys):
    console = Console(file=io.StringIO(), width=200)
    results = quickstart(tmp_path, workers=1, console=console)
    for dataset in ("carla_lead", "navsim", "wod_e2e"):
        manifest = load_manifest(tmp_path / "data" / dataset)
        assert len(manifest) > 0 and set(manifest["dataset"].to_pylist()) == {dataset}
        assert (tmp_path / "data" / dataset / "errors.jsonl").read_text() == ""
    predictions = read_predictions(tmp_path / "runs" / "sim2real" / "predictions.parquet")
    val_keys = set()
    for dataset, split in (("navsim", None), ("wod_e2e", "val")):
        manifest = load_manifest(tmp_path / "data" / dataset).to_pydict()
        val_keys |= {k for k, s in zip(manifest["key"], manifest["split"], strict=True) if split in (None, s)}
    assert {p.key for p in predictions} == val_keys  # the model predicted every validation sample once
    assert (tmp_path / "runs" / "sim2real" / "checkpoints" / "last.ckpt").exists()
    scores = pq.read_table(tmp_path / "runs/sim2real/scores/wod_e2e/rfs@wod-e2e-2025/scores.parquet")
    assert scores.num_rows > 0 and all(4.0 <= s <= 10.0 for s in scores["rfs"].to_pylist())
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary == results
    assert {planner: list(datasets) for planner, datasets in summary.items()} == {
        BASELINE: ["carla_lead", "navsim", "wod_e2e"],
        MODEL: ["navsim", "wod_e2e"],
    }
    assert sum(summary[MODEL][d]["ade"]["frames"] for d in ("navsim", "wod_e2e")) == len(val_keys)

    # the console: stages and the table, Lightning's chatter only in the log file
    text = console.file.getvalue()
    captured = capsys.readouterr()
    assert "Total params" not in text + captured.out + captured.err
    assert "Total params" in (tmp_path / "lightning.log").read_text()  # the model summary, kept
    header = next(line for line in text.splitlines() if "planner" in line)
    columns = [m.column for m in METRICS]
    assert {"ADE", "FDE", "RFS"} <= set(columns)
    assert [cell.strip() for cell in header.strip("┃").split("┃")] == ["planner", "dataset", "samples", *columns]
    rows = [line.strip("│").split("│") for line in text.splitlines() if line.startswith("│")]
    table = {(planner.strip(), dataset.strip()): numbers for planner, dataset, *numbers in rows}
    assert list(table) == [(BASELINE, d) for d in ("carla_lead", "navsim", "wod_e2e")] + [
        (MODEL, d) for d in ("navsim", "wod_e2e")
    ]
    assert all(cell[:-1] == cell[:-1].rstrip() for numbers in table.values() for cell in numbers)  # right-aligned
    model_wod = [cell.strip() for cell in table[MODEL, "wod_e2e"]]
    aggregates = summary[MODEL]["wod_e2e"]
    expected = [f"{aggregates[m.scorer][m.aggregate]:.3f}" if m.applies("wod_e2e") else "-" for m in METRICS]
    assert model_wod == [str(aggregates["ade"]["frames"]), *expected]
    assert table[BASELINE, "navsim"][1 + columns.index("RFS")].strip() == "-"  # NAVSIM has no raters
    assert str(tmp_path / "runs" / "sim2real" / "checkpoints") in text and "lightning.log" in text
