"""``lead-s2r report`` on a tiny scored run (NAVSIM with PDMS, EPDMS and ADE, WOD-E2E with RFS): the files, the
numbers against scores.json, a named failure, a comparison of two runs, bad input, and the pages in a real browser."""

import json
import re
import shutil
import time
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from browser import Chromium, find_chromium

from lead_s2r import cli
from lead_s2r.convert import convert
from lead_s2r.predictions import Prediction, write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.report.run_outputs import load_run
from lead_s2r.report.site import build_report
from lead_s2r.scoring.baselines import predict_constant_velocity
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim, wod_e2e

NAVSIM_T = 0.5 * np.arange(1, 9)
WOD_T = 0.25 * np.arange(1, 21)
METRICS_A = {"navsim": ("pdms@navsim-1.1", "epdms@navsim-2.2", "ade"), "wod_e2e": ("rfs@wod-e2e-2025",)}
METRICS_B = {"navsim": ("pdms@navsim-1.1", "ade"), "wod_e2e": ("rfs@wod-e2e-2025",)}
TRAINING_LOG = "step,epoch,train/loss,val/loss\n9,0,2.5,\n19,0,1.75,\n19,0,,1.9\n29,1,1.25,\n"


def _score(run: Path, predictions: list[Prediction], data: Path, metrics: dict[str, tuple[str, ...]]) -> None:
    run.mkdir(parents=True, exist_ok=True)
    path = write_predictions(run / "predictions.parquet", predictions)
    for dataset, names in metrics.items():
        for metric in names:
            options = {"reference_cache": str(data / "references")} if "pdms" in metric else {}
            out = run / "scores" / dataset / metric.split("@")[0]
            score_predictions(metric, path, [data / dataset], out, allow_missing=True, **options)


def swerve(prediction: Prediction) -> Prediction:
    """The same plan drifting 2.5 m left per second: off the road within the horizon."""
    xy = prediction.xy + np.column_stack([np.zeros(len(prediction.t)), 2.5 * prediction.t])
    return Prediction(prediction.key, prediction.dataset, prediction.t, xy, prediction.yaw)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Converted NAVSIM (1 log) and WOD-E2E (1 segment) data; run A (constant velocity, the first NAVSIM sample
    swerving off the road, a Lightning log and config) and run B (A with two other NAVSIM samples moved 3 m)."""
    root = tmp_path_factory.mktemp("report")
    navsim.generate(root / "raw" / "navsim", count=1, seed=0)
    wod_e2e.generate(root / "raw" / "wod_e2e", count=1, seed=0)
    data = root / "data"
    adapters = {
        "navsim": get_adapter("navsim", maps=str(root / "raw" / "navsim" / "maps")),
        "wod_e2e": get_adapter("wod_e2e"),
    }
    for dataset, adapter in adapters.items():
        assert convert(adapter, root / "raw" / dataset, data / dataset, workers=1).ok
    samples = {d: list(read_samples(data / d, fields=("future",))) for d in adapters}
    grids = {"navsim": NAVSIM_T, "wod_e2e": WOD_T}
    plans = {s["__key__"]: predict_constant_velocity(s, grids[d]) for d in samples for s in samples[d]}
    keys = [s["__key__"] for s in samples["navsim"]]
    off_road, moved = keys[0], keys[2:4]
    plans[off_road] = swerve(plans[off_road])
    _score(root / "A", list(plans.values()), data, METRICS_A)
    (root / "A" / "logs").mkdir()
    (root / "A" / "logs" / "metrics.csv").write_text(TRAINING_LOG)
    (root / "A" / "config.yaml").write_text("seed_everything: 0\nmodel:\n  name: constant-velocity\n")
    for key in moved:
        p = plans[key]
        plans[key] = Prediction(key, p.dataset, p.t, p.xy + np.array([0.0, 3.0]), p.yaw)
    _score(root / "B", list(plans.values()), data, METRICS_B)
    return {"root": root, "data": data, "off_road": off_road, "moved": moved}


class Page(HTMLParser):
    """Links, images, headings and the summary's data cells of one HTML page."""

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.links: list[str] = []
        self.images: list[str] = []
        self.cells: list[tuple[str, str, str, str]] = []  # (folder, key, data-value, text)
        self.headings: list[str] = []
        self._folder = ""
        self._open: tuple[str, ...] | None = None
        self.feed(path.read_text())

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        found = dict(attrs)
        if tag == "a":
            self.links.append(found["href"] or "")
        elif tag == "img":
            self.images.append(found["src"] or "")
        elif tag == "table" and "data-folder" in found:
            self._folder = found["data-folder"] or ""
        elif tag == "td" and "data-key" in found:
            self._open = ("td", found["data-key"] or "", found["data-value"] or "")
        elif tag in ("h1", "h2", "h3"):
            self._open = (tag,)

    def handle_data(self, data: str) -> None:
        if self._open and self._open[0] == "td":
            self.cells.append((self._folder, self._open[1], self._open[2], data))
        elif self._open:
            self.headings.append(data.strip())
        self._open = None


def _aggregate(report: dict[str, Any], dotted: str) -> Any:
    value = report["aggregates"]
    for part in dotted.split("."):
        value = value[part]
    return value


def _check_images(site: Path, page: Path) -> int:
    images = Page(page).images
    for src in images:
        image = cv2.imread(str((page.parent / src).resolve()))
        assert image is not None and image.size > 0, f"{page.name}: {src} does not decode"
        assert (page.parent / src).resolve().is_relative_to(site.resolve())
    return len(images)


@pytest.fixture(scope="module")
def site(runs: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report of run A against run B, two worst samples per metric: built once, read by several tests."""
    site = tmp_path_factory.mktemp("site") / "report"
    started = time.perf_counter()
    assert build_report(runs["root"] / "A", site, baseline=runs["root"] / "B", worst=2) == site / "index.html"
    pages = len(list((site / "samples").glob("*.html")))
    print(f"report of {pages} sample pages in {time.perf_counter() - started:.1f} s")
    return site


def test_report_pages_images_and_summary_numbers(runs: dict[str, Any], site: Path) -> None:
    summary = Page(site / "index.html")
    pages = [link for link in summary.links if link.startswith("samples/")]
    assert len(pages) >= 5 and all((site / link).is_file() for link in pages)
    assert _check_images(site, site / "index.html") >= 4  # histograms per metric and the training curves
    for link in pages:
        assert _check_images(site, site / link) >= 2  # a BEV and at least one camera
    for scores_json in sorted((runs["root"] / "A").rglob("scores.json")):
        report = json.loads(scores_json.read_text())
        folder = scores_json.parent.relative_to(runs["root"] / "A").as_posix()
        cells = {key: (value, text) for f, key, value, text in summary.cells if f == folder}
        numbers = [k for k, v in report["aggregates"].items() if isinstance(v, int | float) and not isinstance(v, bool)]
        assert set(numbers) <= set(cells), folder
        for key, (value, text) in cells.items():
            assert float(value) == _aggregate(report, key), (folder, key)
            assert text == f"{_aggregate(report, key):.4g}"
    assert "Report: A" in summary.headings and "pdms@navsim-1.1 on navsim" in summary.headings
    assert "rfs@wod-e2e-2025 on wod_e2e" in summary.headings


def test_failing_sub_score_is_named_with_the_scorers_step(runs: dict[str, Any], tmp_path: Path) -> None:
    key = runs["off_road"]
    build_report(runs["root"] / "A", tmp_path / "site", samples=[key])
    rows = pq.read_table(runs["root"] / "A" / "scores" / "navsim" / "pdms" / "scores.parquet").to_pylist()
    row = next(row for row in rows if row["key"] == key)
    assert row["drivable_area_compliance"] == 0.0 and row["dac_time_idx"] > 0
    text = (tmp_path / "site" / "samples" / f"{key}.html").read_text()
    assert f"DAC 0: leaves the drivable area at t = {row['dac_time_idx'] * 0.1:.1f} s" in text
    links = Page(tmp_path / "site" / "index.html").links  # a row per metric that scored the sample
    assert {link for link in links if "samples/" in link} == {f"samples/{key}.html"}


def test_comparison_lists_exactly_the_two_samples_that_differ(runs: dict[str, Any], site: Path) -> None:
    listed = set(re.findall(r'<tr data-key="([^"]+)">', (site / "comparison.html").read_text()))
    assert listed == set(runs["moved"])
    assert sorted(path.stem for path in (site / "compare").glob("*.html")) == sorted(runs["moved"])
    for key in runs["moved"]:
        assert _check_images(site, site / "compare" / f"{key}.html") >= 2
    assert "comparison.html" in Page(site / "index.html").links


def test_bad_input_is_one_line_exit_2_and_nothing_written(
    runs: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = str(runs["root"] / "A")
    out = tmp_path / "site"
    (tmp_path / "empty").mkdir()
    cases = {
        "no scores.json below it": [str(tmp_path / "empty"), "--out", str(out)],
        "is not in": [run, "--out", str(out), "--data", str(runs["data"] / "wod_e2e")],
        "no scores of": [run, "--out", str(out), "--samples", "no_such_key"],
        "no such run folder": [str(tmp_path / "missing"), "--out", str(out)],
    }
    for message, argv in cases.items():
        assert cli.main(["report", *argv]) == 2, message
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and "Traceback" not in err and "(and 0 more)" not in err
        assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["empty"]
    out.mkdir()
    (out / "index.html").write_text("an older report")
    assert cli.main(["report", run, "--out", str(out), "--samples", "no_such_key"]) == 2
    assert (out / "index.html").read_text() == "an older report"  # a failed report leaves the old one as it was


def test_report_in_headless_chromium(site: Path, tmp_path: Path) -> None:
    binary = find_chromium()
    if binary is None:
        pytest.skip("no chromium binary on PATH: `apt-get install -y chromium` (Debian) runs this test")
    sample = sorted((site / "samples").glob("*.html"))[0]
    pair = sorted((site / "compare").glob("*.html"))[0]
    expected = {  # page: (headings, fewest images)
        site / "index.html": ({"Report: A", "Scores", "Training curves", "Samples", "Config"}, 4),
        sample: ({f"Sample {sample.stem}", "Sub-scores"}, 2),
        site / "comparison.html": ({"Comparison: B B against A A", "B wins (0)"}, 0),
        pair: ({f"Sample {pair.stem}: A A and B B"}, 2),
    }
    with Chromium(binary) as browser:
        broken = tmp_path / "broken.html"
        broken.write_text('<!DOCTYPE html><html><body><h1>x</h1><img src="missing.png"></body></html>')
        visit = browser.visit(broken)  # the harness sees what it is meant to catch
        assert visit.errors and visit.images == [("missing.png", True, 0)]
        for page, (headings, fewest_images) in expected.items():
            visit = browser.visit(page)
            (tmp_path / f"{page.stem}.png").write_bytes(visit.screenshot)
            assert visit.errors == [], page.name
            assert len(visit.images) >= fewest_images and all(width > 0 for _, _, width in visit.images), visit.images
            assert headings <= set(visit.headings), visit.headings
            assert cv2.imdecode(np.frombuffer(visit.screenshot, np.uint8), cv2.IMREAD_COLOR).shape[1] >= 1000


def test_a_tagged_subset_beside_its_whole_set_is_left_out_of_the_report(runs: dict[str, Any], tmp_path: Path) -> None:
    """`lead-s2r score --tag` rescoring a subset adds no second copy of its samples to the views; alone, it is read."""
    run = tmp_path / "A"
    shutil.copytree(runs["root"] / "A", run)
    rfs = "rfs@wod-e2e-2025"
    tagged = run / "scores" / "wod_e2e" / "rfs-construction"
    data = runs["data"] / "wod_e2e"
    score_predictions(rfs, run / "predictions.parquet", [data], tagged, tag="cluster:Construction", allow_missing=True)
    assert [s.report.get("tag") for s in load_run(run).scores if s.metric == rfs] == [None]
    shutil.rmtree(run / "scores" / "wod_e2e" / "rfs")
    assert [s.report.get("tag") for s in load_run(run).scores if s.metric == rfs] == ["cluster:Construction"]
