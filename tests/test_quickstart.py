"""The README's main job, end to end: every stage must leave real, consistent files behind."""

import json

import pyarrow.parquet as pq
from rich.console import Console

from lead_s2r.predictions import read_predictions
from lead_s2r.quickstart import quickstart
from lead_s2r.shards import load_manifest


def test_quickstart_runs_every_stage(tmp_path):
    results = quickstart(tmp_path, workers=1, console=Console(quiet=True))
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
    scores = pq.read_table(tmp_path / "runs" / "sim2real" / "scores" / "rfs@wod-e2e-2025" / "scores.parquet")
    assert scores.num_rows > 0 and all(4.0 <= s <= 10.0 for s in scores["rfs"].to_pylist())
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary == results and "tfv6 smoke: navsim+wod_e2e ade" in summary
    assert summary["tfv6 smoke: navsim+wod_e2e ade"]["frames"] == len(val_keys)
