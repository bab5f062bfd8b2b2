"""``lead-s2r report --runs`` over a tiny family of runs (two models, two seeds, NAVSIM with a pedestrians-ahead log),
the pages in a real browser (sorting and filtering in the page), ``lead-s2r view``'s Rerun recording read back with
Rerun's own reader, and bad input."""

import json
import re
import shutil
from collections import defaultdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from browser import Chromium, find_chromium

from lead_s2r import cli
from lead_s2r.convert import convert
from lead_s2r.predictions import Prediction, read_predictions, write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.report.model_comparison import ALL_SCENES
from lead_s2r.report.site import build_site
from lead_s2r.scoring.baselines import predict_constant_velocity
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import load_manifest, read_samples
from lead_s2r.synthetic import navsim

NAVSIM_T = 0.5 * np.arange(1, 9)
TAG = "scene_filter:pedestrians_ahead"
PDMS = "pdms@navsim-1.1"
SEEDS = (0, 1)
#: navsim's first fresh log (index 3) is a pedestrians-ahead log (lead_s2r.synthetic.navsim.is_pedestrian_log)
LOGS = 4


def shifted(prediction: Prediction, lateral_m_per_s: float) -> Prediction:
    """The same plan drifting sideways at ``lateral_m_per_s``."""
    xy = prediction.xy + np.column_stack([np.zeros(len(prediction.t)), lateral_m_per_s * prediction.t])
    return Prediction(prediction.key, prediction.dataset, prediction.t, xy, prediction.yaw)


def _score(run: Path, predictions: list[Prediction], data: Path) -> None:
    run.mkdir(parents=True)
    path = write_predictions(run / "predictions.parquet", predictions)
    references = {"reference_cache": str(data.parent / "references")}
    score_predictions(PDMS, path, [data], run / "scores" / "pdms", allow_missing=True, **references)
    score_predictions(PDMS, path, [data], run / "scores" / "pdms-peds", allow_missing=True, tag=TAG, **references)
    score_predictions("ade", path, [data], run / "scores" / "ade", allow_missing=True)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """``runs/navsim/{ego_mlp,ltfv6}/seed{0,1}``: both plan at constant velocity, drifting 0.1 m/s per seed to the
    left; ltfv6 also drifts 3 m/s left in the pedestrians-ahead scenes (it loses there, on drivable area)."""
    root = tmp_path_factory.mktemp("runs")
    raw, data = root / "raw", root / "data" / "navsim"
    navsim.generate(raw, count=LOGS, seed=0)
    adapter = get_adapter("navsim", maps=str(raw / "maps"), tag_filters=str(raw / "scene_filters" / f"{TAG[13:]}.yaml"))
    assert convert(adapter, raw, data, workers=1).ok
    samples = list(read_samples(data, fields=("future",)))
    tagged = {row["key"] for row in load_manifest(data).to_pylist() if TAG in row["tags"]}
    assert 0 < len(tagged) < len(samples)
    for seed in SEEDS:
        plans = [shifted(predict_constant_velocity(s, NAVSIM_T), 0.1 * seed) for s in samples]
        _score(root / "runs" / "navsim" / "ego_mlp" / f"seed{seed}", plans, data)
        plans = [shifted(p, 3.0) if p.key in tagged else p for p in plans]
        _score(root / "runs" / "navsim" / "ltfv6" / f"seed{seed}", plans, data)
    return {"root": root, "data": data, "tagged": tagged, "keys": [s["__key__"] for s in samples]}


@pytest.fixture(scope="module")
def site(runs: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site") / "report"
    pattern = str(runs["root"] / "runs" / "*" / "*" / "seed*")
    assert build_site([pattern], out, compare=("ego_mlp", "ltfv6"), worst=1) == out / "index.html"
    return out


def _row(root: Path, model: str, seed: int, key: str) -> dict[str, Any]:
    table = pq.read_table(root / "runs" / "navsim" / model / f"seed{seed}" / "scores" / "pdms" / "scores.parquet")
    return next(row for row in table.to_pylist() if row["key"] == key)


def _headline(run: Path, folder: str, key: str) -> float:
    return json.loads((run / "scores" / folder / "scores.json").read_text())["aggregates"][key]


def test_index_shows_each_models_mean_and_std_over_seeds(runs: dict[str, Any], site: Path) -> None:
    html = (site / "index.html").read_text()
    for model in ("ego_mlp", "ltfv6"):
        values = [_headline(runs["root"] / "runs" / "navsim" / model / f"seed{s}", "pdms", "pdms") for s in SEEDS]
        assert f"{np.mean(values):.3f} ± {np.std(values, ddof=1):.3f}" in html, model
        for seed in SEEDS:
            assert f'<a href="runs/navsim-{model}-seed{seed}/index.html">navsim / {model} / seed{seed}</a>' in html
    assert f"{PDMS} on {TAG}" in html  # the tagged subset's own column


def test_comparison_puts_the_tagged_scenes_first_with_what_b_loses_there(runs: dict[str, Any], site: Path) -> None:
    html = (site / "models.html").read_text()
    assert "Comparison: B ltfv6 (navsim / ltfv6; seeds 0, 1) against A ego_mlp (navsim / ego_mlp; seeds 0, 1)" in html
    subsets = html.split("<h2>By subset</h2>")[1].split("<h2>")[0]
    assert subsets.index(TAG) < subsets.index(ALL_SCENES)
    rows = html.split('<table class="listing scenes">')[1].split("<tr data-key=")[1:]
    keys = [row.split('"')[1] for row in rows]
    pdms_keys = [key for key, row in zip(keys, rows, strict=True) if f"<td>{PDMS} on navsim</td>" in row]
    assert set(pdms_keys) == set(runs["keys"])
    assert set(pdms_keys[: len(runs["tagged"])]) == runs["tagged"]  # tagged scenes first
    first = next(row for row in rows if f"<td>{PDMS} on navsim</td>" in row)
    assert "drivable_area_compliance" in first and "DAC" in first and 'class="number loss"' in first
    key = first.split('"')[1]
    means = [
        np.mean([_row(runs["root"], model, seed, key)["score"] for seed in SEEDS]) for model in ("ego_mlp", "ltfv6")
    ]
    shown = [float(v) for v in re.findall(r'class="number[^"]*" data-value="([^"]+)"', first)[:3]]
    np.testing.assert_allclose(shown, [means[0], means[1], means[1] - means[0]], rtol=1e-12)  # A, B, B's gain
    assert (site / "models" / f"{keys[0]}.html").is_file()


def test_site_in_headless_chromium_sorts_filters_and_names_runs(
    runs: dict[str, Any], site: Path, tmp_path: Path
) -> None:
    binary = find_chromium()
    if binary is None:
        pytest.skip("no chromium binary on PATH: `apt-get install -y chromium` (Debian) runs this test")
    rows = "Array.from(document.querySelectorAll('table.scenes tbody tr'))"
    visible_keys = f"{rows}.filter(r => !r.hidden).map(r => r.dataset.key)"
    visible_tags = f"{rows}.filter(r => !r.hidden).map(r => r.cells[3].dataset.values)"
    gain_header = "Array.from(document.querySelectorAll('table.scenes th')).find(h => h.textContent === \"B's gain\")"
    choose_tag = (
        "(() => { const s = document.querySelector('select[data-filter-for=\"tags\"]');"
        f" s.value = '{TAG}'; s.dispatchEvent(new Event('change')); return s.options.length; }})()"
    )
    with Chromium(binary) as browser:
        index = browser.visit(site / "index.html", ("Array.from(document.links).map(a => a.textContent)",))
        assert index.errors == []
        assert {f"navsim / {m} / seed{s}" for m in ("ego_mlp", "ltfv6") for s in SEEDS} <= set(index.results[0])
        run_page = browser.visit(site / "runs" / "navsim-ltfv6-seed1" / "index.html")
        assert run_page.errors == [] and "Report: navsim / ltfv6 / seed1" in run_page.headings
        assert all(width > 0 for _, _, width in run_page.images) and len(run_page.images) >= 2
        steps = (visible_keys, f"{gain_header}.click()", f"{gain_header}.click()", visible_keys, choose_tag,
                 visible_keys, visible_tags)  # fmt: skip
        models = browser.visit(site / "models.html", steps)
        assert models.errors == []
        before, _, _, descending, _, filtered, tags = models.results
        assert descending != before and sorted(descending) == sorted(before)  # a click on B's gain re-orders
        gains = browser.visit(
            site / "models.html", (f"{gain_header}.click()", f"{rows}.map(r => +r.cells[6].dataset.value)")
        )
        assert gains.results[1] == sorted(gains.results[1])
        assert filtered and all(TAG in t.split("|") for t in tags)
        assert len(filtered) == 2 * len(runs["tagged"])  # PDMS and ADE rows of every tagged scene, nothing else
        (tmp_path / "models.png").write_bytes(models.screenshot)
        pair = next((site / "models").glob("*.html"))
        pair_visit = browser.visit(pair)
        assert pair_visit.errors == [] and len(pair_visit.images) >= 2
        assert all(width > 0 for _, _, width in pair_visit.images)
        shot = cv2.imdecode(np.frombuffer(models.screenshot, np.uint8), cv2.IMREAD_COLOR)
        assert shot.shape[1] >= 1000


def test_a_glob_that_matches_no_run_is_one_line_exit_2(
    runs: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "site"
    pattern = str(runs["root"] / "runs" / "*" / "*" / "seed*")
    cases = {
        "no run folder matches": ["--runs", str(tmp_path / "runs" / "*" / "*" / "seed*")],
        "--compare tfv6: no scored run of that name": ["--runs", pattern, "--compare", "ego_mlp", "tfv6"],
        "--compare A B compares models of --runs": [str(runs["root"] / "runs" / "navsim" / "ltfv6" / "seed0"),
                                                    "--compare", "ego_mlp", "ltfv6"],
    }  # fmt: skip
    for message, argv in cases.items():
        assert cli.main(["report", *argv, "--out", str(out)]) == 2, message
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and not out.exists() and list(tmp_path.iterdir()) == []


def test_runs_scored_on_different_data_are_one_line_exit_2(
    runs: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A copy of the converted data is other data: a run scored on it is not compared with runs scored on the first."""
    shutil.copytree(runs["root"] / "runs", tmp_path / "runs")
    copy = shutil.copytree(runs["data"], tmp_path / "data" / "navsim")
    scores_json = tmp_path / "runs" / "navsim" / "ltfv6" / "seed1" / "scores" / "pdms" / "scores.json"
    report = json.loads(scores_json.read_text())
    scores_json.write_text(json.dumps(report | {"data": [str(copy)]}))
    out = tmp_path / "site"
    assert cli.main(["report", "--runs", str(tmp_path / "runs" / "*" / "*" / "seed*"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "report runs scored on the same data" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["data", "runs"]


def test_recording_of_a_log_with_a_runs_predictions_reads_back(runs: dict[str, Any], tmp_path: Path) -> None:
    pytest.importorskip("rerun", reason="lead-s2r view needs the viewer extra (rerun-sdk)")
    from rerun.chunk import RrdReader

    run = runs["root"] / "runs" / "navsim" / "ltfv6" / "seed1"
    manifest = load_manifest(runs["data"]).to_pylist()
    log = sorted({row["log"] for row in manifest if row["key"] in runs["tagged"]})[0]
    frames = {row["frame"]: row["key"] for row in manifest if row["log"] == log}
    rrd = tmp_path / "log.rrd"
    assert cli.main(["view", str(run), "--log", log, "--rrd", str(rrd)]) == 0
    rows: dict[str, dict[int, dict[str, Any]]] = defaultdict(dict)
    for chunk in RrdReader(rrd).stream().to_chunks():
        for row in chunk.to_record_batch().to_pylist():
            if "frame" in row:
                rows[chunk.entity_path].setdefault(row["frame"], {}).update(row)
    cameras = [f"/cameras/{name}" for name in ("front", "front_left", "left", "back_left", "front_right", "right",
                                                "back_right", "back")]  # fmt: skip
    expected = {"/ego", "/lidar", "/boxes", "/map/lanes", "/map/areas", "/plan/logged", "/plan/predicted",
                "/scores/pdms/score", "/scores/pdms/drivable_area_compliance", "/scores/ade/ade", *cameras}  # fmt: skip
    assert expected <= set(rows), sorted(set(rows))
    for camera in cameras:
        assert sorted(rows[camera]) == sorted(frames), camera
        assert all(row["EncodedImage:blob"] for row in rows[camera].values())
    frame = sorted(frames)[len(frames) // 2]
    sample = next(s for s in read_samples(runs["data"]) if s["__key__"] == frames[frame])
    assert len(rows["/boxes"][frame]["Boxes3D:centers"]) == len(sample["boxes"]) > 0
    assert any(label.startswith("PEDESTRIAN ") for label in rows["/boxes"][frame]["Boxes3D:labels"])
    predicted = np.asarray(rows["/plan/predicted"][frame]["LineStrips3D:strips"][0])
    plans = {p.key: p for p in read_predictions(run / "predictions.parquet")}
    np.testing.assert_allclose(predicted[:, :2], plans[frames[frame]].xy, atol=1e-6)


def test_a_log_not_in_the_folder_is_one_line_exit_2(
    runs: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("rerun", reason="lead-s2r view needs the viewer extra (rerun-sdk)")
    rrd = tmp_path / "log.rrd"
    assert cli.main(["view", str(runs["data"]), "--log", "no_such_log", "--rrd", str(rrd)]) == 2
    err = capsys.readouterr().err
    assert "--log no_such_log: no such log" in err and err.count("\n") == 1 and list(tmp_path.iterdir()) == []
