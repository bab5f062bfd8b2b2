"""The README's main job: the real-data table (Table 4's layout) from smoke runs scored on held-out logs only."""

import io
import json
import sys

import pytest
import yaml
from rich.console import Console

from lead_s2r.demo import quickstart as qs
from lead_s2r.predictions import read_predictions
from lead_s2r.report.tables import MISSING, collect, to_markdown
from lead_s2r.shards import load_manifest

COLUMNS = ["NAVSIM PDMS", "NAVSIM EPDMS", "WOD-E2E RFS", "NAVSIM ADE", "WOD-E2E ADE", "NAVSIM FDE", "WOD-E2E FDE"]
ROWS = [
    qs.EXPERT,
    "Ego MLP",
    "Ego MLP, before training",
    "LTFv6",
    "LTFv6, before training",
    "LTFv6 + LEAD",
    "LTFv6 + LEAD, before training",
]


def test_without_lead_is_the_lead_twin_minus_its_carla_data(tmp_path):
    for name, twin in (("navsim_ltfv6", "navsim_ltfv6_lead"), ("wod_ltfv6", "wod_ltfv6_lead")):
        without = yaml.safe_load(qs.smoke_config(qs.Training(name, twin, without_lead=True), tmp_path).read_text())
        lead = yaml.safe_load(qs.smoke_config(qs.Training(twin, twin), tmp_path).read_text())
        assert "carla" not in json.dumps(without) and "init_from" not in without["model"]
        assert "carla" in json.dumps(lead["data"]["train"]) or lead["model"]["init_from"].startswith(str(tmp_path))
        qs.drop_carla(lead)
        lead["trainer"]["default_root_dir"] = without["trainer"]["default_root_dir"]
        assert lead == without  # nothing else differs
        assert without["trainer"]["default_root_dir"] == str(tmp_path / "runs" / name)
        assert (without["trainer"]["max_epochs"], without["data"]["steps_per_epoch"]) == qs.STEPS[name]
        assert "quickstart/" not in (tmp_path / f"{name}.yaml").read_text()


def test_twins_train_and_predict_on_disjoint_splits(tmp_path):
    held_out = {"navsim": qs.EVAL_SPLITS["navsim"], "wod": qs.EVAL_SPLITS["wod_e2e"]}
    for training in qs.TRAININGS:
        data = yaml.safe_load(qs.smoke_config(training, tmp_path).read_text())["data"]
        for source, spec in data.get("predict", {}).items():
            assert spec["splits"] == [held_out[source]], training.name
            assert held_out[source] not in data["train"][source]["splits"], training.name


def test_table_spec_is_table4_over_the_quickstart_rows():
    spec = qs.table_spec()
    assert [c.name for c in spec.columns] == COLUMNS
    assert [r.name for r in spec.rows] == ROWS
    rfs = COLUMNS.index("WOD-E2E RFS")
    paper = {row.name: row.paper[rfs] for row in spec.rows}
    assert paper == dict(
        zip(ROWS, [8.10, 7.31, None, 7.51, None, 7.76, None], strict=True)
    )  # recipes/paper/table4.yaml
    assert all(value is None for row in spec.rows for i, value in enumerate(row.paper) if i != rfs)


def _scores(pdms: float, ade: float) -> dict:
    navsim = {"pdms@navsim-1.1": {"pdms": pdms}, "epdms@navsim-2.2": {"epdms": pdms / 2}}
    return {"navsim": {**navsim, "ade": {"ade": ade, "fde": 2 * ade}}}


RESULTS = {
    "expert": {**_scores(0.9375, 0.0), "wod_e2e": {"rfs@wod-e2e-2025": {"rfs": 8.0}, "ade": {"ade": 0, "fde": 0}}},
    "navsim_ltfv6/trained": _scores(0.5, 1.5),
    "wod_ltfv6/trained": {"wod_e2e": {"rfs@wod-e2e-2025": {"rfs": 6.5}, "ade": {"ade": 1.25, "fde": 3.0}}},
    "navsim_ltfv6/untrained": _scores(0.0, 9.0),  # its WOD-E2E run is missing
}


def test_a_row_joins_the_navsim_and_wod_runs_of_one_model(tmp_path):
    spec = qs.table_spec()
    lines = to_markdown(spec, collect(spec, qs.table_runs(RESULTS, tmp_path))).splitlines()
    expert = "| Expert (logged) | 93.75 | – | 46.88 | – | 8.00 | 8.10 | 0.00 | – | 0.00 | – | 0.00 | – | 0.00 | – |"
    assert expert in lines
    assert "| LTFv6 | 50.00 | – | 25.00 | – | 6.50 | 7.51 | 1.50 | – | 1.25 | – | 3.00 | – | 3.00 | – |" in lines
    m = MISSING
    untrained = f"| LTFv6, before training | 0.00 | – | 0.00 | – | {m} | – | 9.00 | – | {m} | – | 18.00 | – | {m} | – |"
    assert untrained in lines
    assert f"| Ego MLP | {m} | – | {m} | – | {m} | 7.31 |" in "\n".join(lines)


def test_console_shows_one_table_per_dataset_within_80_columns(tmp_path):
    spec = qs.table_spec()
    console = Console(file=io.StringIO(), width=80)
    for grid in qs.tables(spec, collect(spec, qs.table_runs(RESULTS, tmp_path))):
        console.print(grid)
    lines = console.file.getvalue().splitlines()
    assert max(len(line) for line in lines) <= 80 and "…" not in console.file.getvalue()
    rows = [" ".join(line.strip("│┃ ").replace("│", " ").replace("┃", " ").split()) for line in lines]
    assert "NAVSIM: held-out test logs" in rows and "WOD-E2E: held-out val logs" in rows
    assert "model PDMS EPDMS ADE FDE" in rows  # the paper has no NAVSIM numbers in recipes/paper/table4.yaml
    assert "model RFS paper ADE FDE" in rows
    m = MISSING
    navsim = ["Expert (logged) 93.75 46.88 0.00 0.00", f"Ego MLP {m} {m} {m} {m}", "LTFv6 50.00 25.00 1.50 3.00"]
    wod = ["Expert (logged) 8.00 8.10 0.00 0.00", f"Ego MLP {m} 7.31 {m} {m}", "LTFv6 6.50 7.51 1.25 3.00"]
    before = ["before training 0.00 0.00 9.00 18.00", f"before training {m} – {m} {m}"]
    for row in navsim + wod + before:
        assert row in rows
    assert rows[rows.index(navsim[2]) + 1] == before[0]  # a model's untrained row sits under it
    assert rows[rows.index(wod[2]) + 1] == before[1]
    assert all(line.startswith("│   before training ") for line in lines if "before training" in line)


@pytest.mark.slow
def test_quickstart_scores_every_model_before_and_after_training_on_held_out_logs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI reads it beside its args
    monkeypatch.setattr(qs, "STEPS", dict.fromkeys(qs.STEPS, (1, 2)))
    small = {"navsim": ({"trainval": 2, "test": 1}, {"maps": "maps"}), "wod_e2e": ({"train": 2, "val": 2}, {})}
    monkeypatch.setattr(qs, "PLAN", {**qs.PLAN, **small, "carla_lead": (None, {})})
    console = Console(file=io.StringIO(), width=80)
    results = qs.quickstart(tmp_path, workers=1, console=console)

    held_out = set()
    for dataset, split in qs.EVAL_SPLITS.items():
        manifest = load_manifest(tmp_path / "data" / dataset).to_pydict()
        assert set(manifest["split"]) == {split, {"navsim": "trainval", "wod_e2e": "train"}[dataset]}
        held_out |= {k for k, s in zip(manifest["key"], manifest["split"], strict=True) if s == split}
    for training in (t for t in qs.TRAININGS if t.predicts):
        for stage in (qs.UNTRAINED, qs.TRAINED):
            predicted = {
                p.key for p in read_predictions(tmp_path / "runs" / training.name / stage / "predictions.parquet")
            }
            assert predicted <= held_out and predicted, (training.name, stage)
        assert (tmp_path / "runs" / training.name / "checkpoints" / "last.ckpt").exists()
    assert set(results) == {"expert"} | {
        f"{t.name}/{s}" for t in qs.TRAININGS if t.predicts for s in ("untrained", "trained")
    }
    assert results["expert"]["wod_e2e"]["ade"]["ade"] == 0.0  # the logged future replayed
    assert json.loads((tmp_path / "summary.json").read_text()) == results

    text = console.file.getvalue()
    captured = capsys.readouterr()
    assert "Total params" not in text + captured.out + captured.err
    assert "Total params" in (tmp_path / "lightning.log").read_text()  # the model summary, kept
    markdown = (tmp_path / "table" / "table4.md").read_text()
    for row in ROWS:
        assert f"| {row} |" in markdown and qs.console_name(row) in text
    assert max(len(line) for line in text.splitlines()) <= 80
    assert MISSING not in markdown  # every row scored on both datasets
    assert str(tmp_path / "table") in text and "lightning.log" in text
    assert str(tmp_path / "report" / "index.html") in "".join(text.split())  # the web report, printed
    assert (tmp_path / "report" / "comparison.html").is_file()
