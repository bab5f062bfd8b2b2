"""The README's main job: the real-data table (Table 4's layout) from smoke runs scored on held-out logs only."""

import io
import json
import multiprocessing
import os
import signal
import sys
import threading
import time

import pytest
import torch
import yaml
from rich.console import Console

from lead_s2r.cli import main
from lead_s2r.demo import quickstart as qs
from lead_s2r.demo import table4
from lead_s2r.predictions import read_predictions
from lead_s2r.report.tables import MISSING, collect
from lead_s2r.shards import load_manifest

COLUMNS = [
    "NAVSIM PDMS",
    "NAVSIM PDMS, needs perception",
    "NAVSIM EPDMS",
    "WOD-E2E RFS",
    "WOD-E2E RFS, needs perception",
    "NAVSIM ADE",
    "WOD-E2E ADE",
]
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
        assert "carla" not in json.dumps(without["data"]) and "init_from" not in without["model"]
        assert without["model"]["model"]["init_args"]["config"]["use_carla_data"] is False  # no CARLA heads either
        assert "carla" in json.dumps(lead["data"]["train"]) or lead["model"]["init_from"].startswith(str(tmp_path))
        qs.drop_carla(lead)
        lead["trainer"]["default_root_dir"] = without["trainer"]["default_root_dir"]
        assert lead == without  # nothing else differs
        family, model = name.split("_", 1)  # the recipes' layout: runs/<family>/<name>/seed<k>
        assert without["trainer"]["default_root_dir"] == str(tmp_path / "runs" / family / model / "seed0")
        assert (without["trainer"]["max_epochs"], without["data"]["steps_per_epoch"]) == qs.STEPS[name]
        assert without["data"]["val"] == without["data"]["predict"]  # the loss curves' validation side
        assert "quickstart/" not in (tmp_path / f"{name}-seed0.yaml").read_text()


def test_a_seed_sets_the_run_its_folder_and_the_pretraining_it_starts_from(tmp_path):
    training = next(t for t in qs.TRAININGS if t.name == "wod_ltfv6_lead")
    config = yaml.safe_load(qs.smoke_config(training, tmp_path, seed=2).read_text())
    assert config["seed_everything"] == 2
    assert config["trainer"]["default_root_dir"] == str(tmp_path / "runs" / "wod" / "ltfv6_lead" / "seed2")
    pretraining = tmp_path / "runs" / "wod" / "ltfv6_pretrain" / "seed2"
    assert config["model"]["init_from"] == str(pretraining / "checkpoints" / "last.ckpt")


def test_twins_train_and_predict_on_disjoint_splits(tmp_path):
    held_out = {"navsim": qs.EVAL_SPLITS["navsim"], "wod": qs.EVAL_SPLITS["wod_e2e"]}
    for training in qs.TRAININGS:
        data = yaml.safe_load(qs.smoke_config(training, tmp_path).read_text())["data"]
        for source, spec in data.get("predict", {}).items():
            assert spec["splits"] == [held_out[source]], training.name
            assert held_out[source] not in data["train"][source]["splits"], training.name


def test_table_spec_is_table4_over_the_quickstart_rows():
    spec = table4.table_spec(qs.SEEDS)
    assert [c.name for c in spec.columns] == COLUMNS
    assert [r.name for r in spec.rows] == ROWS
    papers = {  # recipes/paper/table4.yaml, as the paper prints them; none for the untrained rows
        "WOD-E2E RFS": ["8.10", "7.31", None, "7.51", None, "7.76", None],
        "NAVSIM PDMS": ["94.5", "65.6", None, "85.4", None, "86.4", None],
        "NAVSIM EPDMS": ["51.3", "12.7", None, "28.3", None, "31.4", None],
    }
    for i, column in enumerate(COLUMNS):
        assert [row.paper[i] for row in spec.rows] == papers.get(column, [None] * len(ROWS)), column
    assert spec.seeds == qs.SEEDS == (0, 1, 2)


def _scores(pdms: float, ade: float) -> dict:
    navsim = {"pdms@navsim-1.1": {"pdms": pdms}, "epdms@navsim-2.2": {"epdms": pdms / 2}}
    needs = {"pdms@navsim-1.1#scene_filter:pedestrians_ahead": {"pdms": 0.8 * pdms}}  # the tagged subset's
    return {"navsim": {**navsim, **needs, "ade": {"ade": ade, "fde": 2 * ade}}}


def _wod(rfs: float, ade: float) -> dict:
    needs = {"rfs@wod-e2e-2025#cluster:Pedestrian": {"rfs": rfs - 1}}
    return {"wod_e2e": {"rfs@wod-e2e-2025": {"rfs": rfs}, **needs, "ade": {"ade": ade, "fde": 2 * ade}}}


RESULTS = {
    "expert": {**_scores(0.9375, 0.0), **_wod(8.0, 0.0)},
    **{f"navsim_ltfv6/seed{seed}/trained": _scores(pdms, 1.5) for seed, pdms in enumerate((0.5, 0.6, 0.7))},
    **{f"wod_ltfv6/seed{seed}/trained": _wod(rfs, 1.25) for seed, rfs in enumerate((6.0, 6.5, 7.0))},
    "navsim_ltfv6/seed0/untrained": _scores(0.0, 9.0),  # seeds 1 and 2 and its WOD-E2E runs are missing
}


def test_a_row_joins_the_navsim_and_wod_runs_of_one_model_over_seeds(tmp_path):
    shown = table4.build_table4(RESULTS, tmp_path, qs.SEEDS)
    assert shown[-2] == table4.table_spec(qs.SEEDS).notes and shown[-1].startswith("Camera reliance")
    assert sorted(path.name for path in (tmp_path / "table").iterdir()) == ["table4.csv", "table4.md", "table4.tex"]
    lines = (tmp_path / "table" / "table4.md").read_text().splitlines()
    zero = "0.00 ± 0.00"
    navsim = "| Expert (logged) | 93.75 ± 0.00 | 94.5 | 75.00 ± 0.00 | – | 46.88 ± 0.00 | 51.3 |"
    wod = f"8.00 ± 0.00 | 8.10 | 7.00 ± 0.00 | – | {zero} | – | {zero} | – |"
    assert f"{navsim} {wod}" in lines  # deterministic: the same scores for every seed
    navsim = "| LTFv6 | 60.00 ± 10.00 | 85.4 | 48.00 ± 8.00 | – | 30.00 ± 5.00 | 28.3 |"
    wod = "6.50 ± 0.50 | 7.51 | 5.50 ± 0.50 | – | 1.50 ± 0.00 | – | 1.25 ± 0.00 | – |"
    assert f"{navsim} {wod}" in lines
    m = MISSING
    before = f"| LTFv6, before training | 0.00* | – | 0.00* | – | 0.00* | – | {m} | – | {m} | – | 9.00* | – | {m} | – |"
    assert before in lines
    assert f"| Ego MLP | {m} | 65.6 | {m} | – | {m} | 12.7 | {m} | 7.31 |" in "\n".join(lines)


def test_console_shows_one_table_per_dataset_within_80_columns(tmp_path):
    spec = table4.table_spec(qs.SEEDS)
    console = Console(file=io.StringIO(), width=80)
    widest = {f"navsim_ltfv6_lead/seed{seed}/trained": _scores(pdms, 10.5) for seed, pdms in enumerate((1, 0, 0.2))}
    for grid in table4.tables(spec, collect(spec, table4.table_runs(RESULTS | widest, tmp_path, qs.SEEDS))):
        console.print(grid)
    lines = console.file.getvalue().splitlines()
    assert max(len(line) for line in lines) <= 80 and "…" not in console.file.getvalue()
    rows = [" ".join(line.split()) for line in lines]
    assert "NAVSIM: held-out test logs" in rows and "WOD-E2E: held-out val logs" in rows
    assert "PDMS, needs" in rows and "model PDMS paper perception EPDMS paper ADE" in rows
    assert "RFS, needs" in rows and "model RFS paper perception ADE" in rows
    m = MISSING
    navsim = [
        "Expert 93.75 ± 0.00 94.5 75.00 ± 0.00 46.88 ± 0.00 51.3 0.00 ± 0.00",
        f"Ego MLP {m} 65.6 {m} {m} 12.7 {m}",
        "LTFv6 60.00 ± 10.00 85.4 48.00 ± 8.00 30.00 ± 5.00 28.3 1.50 ± 0.00",
        "LTFv6 + LEAD 40.00 ± 52.92 86.4 32.00 ± 42.33 20.00 ± 26.46 31.4 10.50 ± 0.00",  # the widest: unwrapped
    ]
    wod = ["Expert 8.00 ± 0.00 8.10 7.00 ± 0.00 0.00 ± 0.00", f"Ego MLP {m} 7.31 {m} {m}"]
    wod.append("LTFv6 6.50 ± 0.50 7.51 5.50 ± 0.50 1.25 ± 0.00")
    before = ["untrained 0.00* – 0.00* 0.00* – 9.00*", f"untrained {m} – {m} {m}"]
    for row in navsim + wod + before:
        assert row in rows
    assert rows[rows.index(navsim[2]) + 1] == before[0]  # a model's untrained row sits under it
    assert rows[rows.index(wod[2]) + 1] == before[1]
    indent = {line.index(line.lstrip()) for line in lines if line.lstrip().startswith(("LTFv6", "Ego MLP"))}
    assert {line.index("untrained") for line in lines if "untrained" in line} == {min(indent) + 2}


@pytest.mark.slow
def test_quickstart_scores_every_model_before_and_after_training_on_held_out_logs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI reads it beside its args
    monkeypatch.setattr(qs, "STEPS", dict.fromkeys(qs.STEPS, (1, 2)))
    monkeypatch.setattr(qs, "SEEDS", (0, 1))
    # the held-out NAVSIM log 3 and WOD-E2E segment 1 have pedestrians ahead: the "needs perception" columns
    small = {"navsim": ({"trainval": 3, "test": 1}, qs.PLAN["navsim"][1]), "wod_e2e": ({"train": 2, "val": 2}, {})}
    monkeypatch.setattr(qs, "PLAN", {**qs.PLAN, **small, "carla_lead": (None, {})})
    console = Console(file=io.StringIO(), width=80)
    results = qs.quickstart(tmp_path, workers=2, console=console)  # trainings in two forked processes

    output = console.file.getvalue()
    text = output.replace("\n", "")  # rich wraps long paths
    held_out = set()
    for dataset, split in qs.EVAL_SPLITS.items():
        manifest = load_manifest(tmp_path / "data" / dataset).to_pydict()
        assert set(manifest["split"]) == {split, {"navsim": "trainval", "wod_e2e": "train"}[dataset]}
        held_out |= {k for k, s in zip(manifest["key"], manifest["split"], strict=True) if s == split}
    for training, seed in ((t, seed) for t in qs.TRAININGS for seed in qs.SEEDS):
        dataset, name = qs.home(training)
        run = qs.run_folder(tmp_path, dataset, name, seed)
        for stage in (qs.UNTRAINED, qs.TRAINED) if training.predicts else ():
            predictions = qs.stage_folder(tmp_path, training, dataset, stage, seed) / "predictions.parquet"
            predicted = {p.key for p in read_predictions(predictions)}
            assert predicted <= held_out and predicted, (training.name, stage)
        assert (run / "checkpoints" / "last.ckpt").exists()
        assert (run / qs.LOSS_CURVES).read_bytes().startswith(b"\x89PNG") and str(run / qs.LOSS_CURVES) in text
    stages = ("untrained", "trained")
    runs = {f"{t.name}/seed{seed}/{s}" for t in qs.TRAININGS if t.predicts for seed in qs.SEEDS for s in stages}
    assert set(results) == {"expert"} | runs
    assert results["expert"]["wod_e2e"]["ade"]["ade"] == 0.0  # the logged future replayed
    assert json.loads((tmp_path / "summary.json").read_text()) == results
    for run, by_dataset in results.items():  # the camera models' reliance on their cameras, beside their scores
        for dataset, scores in by_dataset.items():
            has_cameras = run != "expert" and not run.startswith("ego_mlp/")
            assert (qs.CAMERA_RELIANCE in scores) == has_cameras, (run, dataset)
            if has_cameras:
                assert scores[qs.CAMERA_RELIANCE]["samples"] > 0 and scores[qs.CAMERA_RELIANCE]["mean_m"] >= 0
    for label in table4.LABELS.values():  # the camera models' reliance, one line each
        assert f"  {label}, LTFv6: " in output and f"  {label}, LTFv6 + LEAD: " in output
    assert ", Ego MLP: " not in output  # no cameras

    captured = capsys.readouterr()
    assert "Total params" not in text + captured.out + captured.err
    assert "Total params" in (tmp_path / "lightning.log").read_text()  # the model summary, kept
    markdown = (tmp_path / "table" / "table4.md").read_text()
    for row in ROWS:
        assert f"| {row} |" in markdown and table4.console_name(row) in text
    assert max(len(line) for line in output.splitlines()) <= 80
    assert MISSING not in markdown  # every row scored on both datasets
    assert str(tmp_path / "table") in text and "lightning.log" in text
    assert str(tmp_path / "report" / "index.html") in "".join(text.split())  # the web report, printed
    assert (tmp_path / "report" / "models.html").is_file()  # LTFv6 against the Ego MLP

    # the quickstart's runs are laid out as the recipes', so the paper's Table 4 spec reads them as they are
    assert main(["table", "--spec", "table4", "--runs", str(tmp_path / "runs" / "*" / "*" / "seed*")]) == 0
    printed = capsys.readouterr().out
    expert = results["expert"]
    rfs, pdms = expert["wod_e2e"]["rfs@wod-e2e-2025"]["rfs"], expert["navsim"]["pdms@navsim-1.1"]["pdms"]
    no_navsim = f"| {MISSING} | – " * 3  # NAVSIM PDMS, its needs-perception subset, EPDMS; one seed asked
    assert f"| Expert (WOD-E2E) {no_navsim}| {rfs:.2f} | 8.10 |" in printed
    assert f"| Expert (NAVSIM) | {100 * pdms:.2f} | 94.5 |" in printed
    lead = next(line for line in printed.splitlines() if line.startswith("| LTFv6 + LEAD (WOD-E2E) |"))
    assert "* | 7.76 |" in lead and f"| {MISSING}* |" not in lead  # seed 0 of the three, scored

    # a run in a forked process gives what it gives in this one, bit for bit: one torch thread either way
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        again, _ = qs.train_chain((qs.TRAININGS[1],), 1, tmp_path, {dataset: qs.ScoringCaches() for dataset in qs.PLAN})
    finally:
        torch.set_num_threads(threads)
    assert set(again) == {"navsim_ltfv6/seed1/untrained", "navsim_ltfv6/seed1/trained"}
    assert again == {key: results[key] for key in again}


def _slow_chain(chain: tuple, seed: int, out, caches=None) -> tuple[dict, list[str]]:
    time.sleep(120)  # a training in flight
    return {}, []


def test_ctrl_c_stops_the_trainings_in_flight_at_once(tmp_path, monkeypatch, request):
    """Ctrl-C reaches every process of the terminal's group: the training processes leave it to the quickstart,
    which stops them instead of waiting for their runs (Lightning would catch it in there and go on scoring)."""
    monkeypatch.setattr(qs, "train_chain", _slow_chain)  # forked: the processes run the patched module
    # a SIGTERM handler the processes inherit (as after an earlier Lightning fit or Ray driver in this process)
    previous = signal.signal(signal.SIGTERM, lambda *_: None)
    request.addfinalizer(lambda: signal.signal(signal.SIGTERM, previous))

    pressed: list[float] = []
    others = set(multiprocessing.active_children())  # left by earlier tests: not the quickstart's to stop

    def ctrl_c() -> None:
        waited = time.monotonic()  # until both training processes have started (bounded: the test must end)
        while len(set(multiprocessing.active_children()) - others) < 2 and time.monotonic() - waited < 60:
            time.sleep(0.1)
        time.sleep(1)
        for process in set(multiprocessing.active_children()) - others:
            os.kill(process.pid, signal.SIGINT)
        pressed.append(time.monotonic())
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=ctrl_c, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        qs.train_every_seed(tmp_path, 2, Console(file=io.StringIO()), time.perf_counter(), {})
    assert time.monotonic() - pressed[0] < 30  # a chain in flight sleeps for 120 s
    assert set(multiprocessing.active_children()) <= others


def test_ctrl_c_in_any_verb_is_one_line_and_status_130(monkeypatch, capsys):
    def interrupted(argv: list[str], from_shell: bool) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr("lead_s2r.cli._run", interrupted)
    assert main(["convert", "--help"]) == 130
    assert capsys.readouterr().err == "interrupted\n"
