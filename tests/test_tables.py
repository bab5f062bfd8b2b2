"""lead-s2r table: runs found from saved configs, mean ± std over seeds worked by hand, missing seeds marked."""

import csv
import io
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from lead_s2r.cli import main
from lead_s2r.report.figures import infraction_bars
from lead_s2r.report.tables import MISSING, TableError, build_table, collect, find_runs, load_spec, run_identity

RFS = "rfs@wod-e2e-2025"
B2D = "carla-leaderboard-2.0/bench2drive"


def make_run(root: Path, run_id: str, seed: int, scores: dict[str, dict[str, Any]]) -> Path:
    """A run folder as `lead-s2r fit` + `score` leave it: a saved config in the log folder, scores below."""
    run = root / run_id / f"seed{seed}"
    logs = run / "lightning_logs" / "version_0"
    logs.mkdir(parents=True)
    config = {"seed_everything": seed, "trainer": {"default_root_dir": f"/scratch/runs/{run_id}/seed{seed}"}}
    (logs / "config.yaml").write_text(yaml.safe_dump(config))
    for i, (metric, aggregates) in enumerate(scores.items()):
        (run / f"scores{i}").mkdir()
        (run / f"scores{i}" / "scores.json").write_text(json.dumps({"metric": metric, "aggregates": aggregates}))
    return run


def write_spec(folder: Path) -> Path:
    spec = {
        "title": "Table 4: real data",
        "columns": [
            {"name": "RFS", "metric": RFS, "key": "rfs"},
            {"name": "red lights / 100 km", "metric": B2D, "key": "infractions_per_100km.red_light"},
        ],
        "rows": [
            {"name": "LTFv6", "run": "wod/ltfv6", "paper": [7.51, None]},
            {"name": "LTFv6 + LEAD", "run": "wod/ltfv6_lead", "paper": [7.76, None]},
            {"name": "Ego MLP", "run": "wod/ego_mlp", "paper": [7.31, None]},
        ],
        "figure": {"metric": B2D, "infractions": ["red_light", "collisions_vehicle"]},
    }
    path = folder / "table4.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


@pytest.fixture
def runs(tmp_path) -> Path:
    root = tmp_path / "runs"
    for seed, rfs, red in ((0, 7.5, 1.0), (1, 7.7, 2.0), (2, 7.9, 6.0)):
        make_run(root, "wod/ltfv6", seed, {RFS: {"rfs": rfs}, B2D: {"infractions_per_100km": {"red_light": red}}})
    for seed, rfs in ((0, 7.0), (2, 7.4)):  # seed 1 never finished
        make_run(root, "wod/ltfv6_lead", seed, {RFS: {"rfs": rfs}})
    return root


def test_mean_and_std_over_three_seeds_match_a_hand_computation(tmp_path, runs):
    spec = load_spec(write_spec(tmp_path))
    cells = collect(spec, find_runs([str(runs / "*" / "*" / "seed*")]))
    rfs = cells[0][0]
    assert rfs.mean == pytest.approx(7.7)
    assert rfs.std == pytest.approx(0.2)  # sqrt((0.04 + 0 + 0.04) / 2)
    red = cells[0][1]
    assert red.mean == pytest.approx(3.0)
    assert red.std == pytest.approx(np.sqrt((4 + 1 + 9) / 2))
    assert rfs.missing_seeds == red.missing_seeds == ()


def test_missing_seeds_and_missing_runs_are_marked(tmp_path, runs):
    markdown = build_table(write_spec(tmp_path), [str(runs / "*" / "*" / "seed*")], tmp_path / "out")
    lines = markdown.splitlines()
    assert "| LTFv6 | 7.70 ± 0.20 | 7.51 | 3.00 ± 2.65 | – |" in lines
    assert "| LTFv6 + LEAD | 7.20 ± 0.28* | 7.76 | missing | – |" in lines
    assert f"| Ego MLP | {MISSING} | 7.31 | {MISSING} | – |" in lines
    assert "* LTFv6 + LEAD / RFS: seeds [1] missing" in lines
    rows = list(csv.DictReader(io.StringIO((tmp_path / "out" / "table4.csv").read_text())))
    lead = next(r for r in rows if r["model"] == "LTFv6 + LEAD" and r["column"] == "RFS")
    assert (lead["n"], lead["missing_seeds"], float(lead["mean"])) == ("2", "1", pytest.approx(7.2))
    latex = (tmp_path / "out" / "table4.tex").read_text()
    assert r"7.70 $\pm$ 0.20" in latex and r"\begin{tabular}{lrrrr}" in latex
    assert (tmp_path / "out" / "table4.png").exists()


def test_cli_prints_the_table(tmp_path, runs, capsys):
    spec = write_spec(tmp_path)
    assert main(["table", "--spec", str(spec), "--runs", *map(str, sorted(runs.glob("*/*/seed*")))]) == 0
    assert "| LTFv6 | 7.70 ± 0.20 | 7.51 |" in capsys.readouterr().out


def test_run_identity_and_errors(tmp_path, runs):
    config = next(runs.glob("wod/ltfv6/seed2/**/config.yaml"))
    assert run_identity(config) == ("/scratch/runs/wod/ltfv6", 2)
    make_run(tmp_path / "again", "wod/ltfv6", 2, {RFS: {"rfs": 1.0}})
    spec = load_spec(write_spec(tmp_path))
    with pytest.raises(TableError, match="seed 2 found twice"):
        collect(spec, find_runs([str(runs / "*" / "*" / "seed*"), str(tmp_path / "again" / "*" / "*" / "seed*")]))
    config.write_text(yaml.safe_dump({"seed_everything": True, "trainer": {"default_root_dir": "x"}}))
    with pytest.raises(TableError, match="fixed integer seed"):
        run_identity(config)
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        yaml.safe_dump(
            {
                "title": "t",
                "columns": [{"name": "a", "metric": RFS, "key": "rfs"}],
                "rows": [{"name": "r", "run": "x", "paper": [1.0, 2.0]}],
            }
        )
    )
    with pytest.raises(TableError, match="2 paper numbers for 1 columns"):
        load_spec(bad)


def test_figure_bar_heights_follow_the_rates(tmp_path):
    out = tmp_path / "fig.png"
    figure = infraction_bars({"A": {"red_light": 50.0, "x": 25.0}, "B": None}, ["red_light", "x"], out, "t")
    assert cv2.imread(str(out)).shape[:2] == (440, 620)  # 100 dpi, 1.6 in a group + 3 in of axis and legend
    axes = figure.axes[0]
    assert [bar.get_height() for bar in axes.patches] == [50.0, 0.0, 25.0, 0.0]  # red_light for A, B; then x
    assert [text.get_text() for text in axes.texts] == ["no results"]  # B keeps its slot, labelled


def test_figure_spec_names_leaderboard_infractions(tmp_path):
    spec = yaml.safe_load(write_spec(tmp_path).read_text())
    spec["figure"]["infractions"] = ["red_lights"]
    bad = tmp_path / "bad_figure.yaml"
    bad.write_text(yaml.safe_dump(spec))
    with pytest.raises(TableError, match=r"unknown \['red_lights'\]"):
        load_spec(bad)


@pytest.mark.parametrize(
    ("infractions", "expected"),
    [
        ([{"red_light": 1}], r"figure.infractions is \[\{'red_light': 1\}\], not a list of str"),
        ("red_light", "'red_light', not a list of str"),
    ],
)
def test_figure_infractions_of_another_type_are_one_line(tmp_path, infractions, expected):
    """Found by the fuzz (seed 9029): a dict among the infractions was Python's 'unhashable type'."""
    spec = yaml.safe_load(write_spec(tmp_path).read_text())
    spec["figure"]["infractions"] = infractions
    bad = tmp_path / "bad_figure.yaml"
    bad.write_text(yaml.safe_dump(spec))
    with pytest.raises(TableError, match=expected):
        load_spec(bad)


def test_table5_from_leaderboard_results_end_to_end(tmp_path):
    """results JSON -> carla-metrics into each seed's run folder -> the shipped Table 5 spec, by name."""
    from test_carla_leaderboard import VEHICLE_HIT, record, results_file

    from lead_s2r.scoring.carla_leaderboard import carla_metrics

    root = tmp_path / "runs"
    for seed, hits in ((0, 0), (1, 1), (2, 2)):  # routes with a vehicle hit each: DS 100 or 60 per route
        run = make_run(root, "carla/tfv6_resnet34", seed, {})
        for benchmark, n in (("bench2drive", 220), ("longest6", 36), ("town13", 20)):
            records = [
                record(i, infractions={"collisions_vehicle": [VEHICLE_HIT]} if i < hits else {}) for i in range(n)
            ]
            carla_metrics([results_file(tmp_path, records, f"{benchmark}{seed}.json")], benchmark, run / benchmark)
    markdown = build_table("table5", [str(root / "carla" / "*" / "seed*")], tmp_path / "tables")
    ds = [100 - 40 * hits / 220 for hits in (0, 1, 2)]  # Bench2Drive DS per seed
    mean, std = np.mean(ds), np.std(ds, ddof=1)
    assert f"| TFv6 ResNet-34 | {mean:.2f} ± {std:.2f} | 94.7 ± 0.7 |" in markdown
    assert "| TFv6 RegNetY-032 (full) | missing | 95.2 ± 0.3 |" in markdown
    assert markdown.splitlines()[4].endswith("| missing | 5.24 |")  # the paper's numbers as printed
    figure = cv2.imread(str(tmp_path / "tables" / "table5.png"))
    assert figure is not None and figure.shape[1] > 6 * 160  # one bar group per row of the table


def test_a_run_folder_named_seed_k_needs_no_config_and_predict_configs_do_not_count(tmp_path, runs):
    expert = tmp_path / "runs" / "wod" / "ego_mlp" / "seed1"  # scores only, e.g. `score --planner human --out`
    (expert / "scores").mkdir(parents=True)
    (expert / "scores" / "scores.json").write_text(json.dumps({"metric": RFS, "aggregates": {"rfs": 6.5}}))
    predict_logs = runs / "wod" / "ltfv6" / "seed1" / "lightning_logs" / "version_1"
    predict_logs.mkdir()  # `lead-s2r predict --trainer.default_root_dir .../seed1` without --seed_everything 1
    (predict_logs / "predict_config.yaml").write_text(yaml.safe_dump({"seed_everything": 0}))
    cells = collect(load_spec(write_spec(tmp_path)), find_runs([str(runs / "*" / "*" / "seed*")]))
    assert cells[0][0].mean == pytest.approx(7.7) and cells[2][0].values == (6.5,)
    (predict_logs / "config.yaml").write_text(yaml.safe_dump({"seed_everything": 0}))  # a fit of seed 0 in seed1/
    with pytest.raises(TableError, match=r"is 0 in the folder of seed 1; train with --seed_everything 1"):
        find_runs([str(runs / "wod" / "ltfv6" / "seed1")])


def test_any_subset_of_families_makes_a_table(tmp_path, runs, capsys):
    spec = write_spec(tmp_path)
    patterns = [str(runs / "navsim" / "*" / "seed*"), str(runs / "wod" / "*" / "seed*")]  # no navsim run yet
    assert main(["table", "--spec", str(spec), "--runs", *patterns]) == 0
    assert "| LTFv6 | 7.70 ± 0.20 | 7.51 |" in capsys.readouterr().out
    assert main(["table", "--spec", str(spec), "--runs", patterns[0]]) == 2
    assert f"--runs: no run folder matches {patterns[0]}" in capsys.readouterr().err
    assert main(["table", "--spec", str(spec), "--runs", str(runs / "navsim")]) == 2
    assert f"--runs: no such directory {runs / 'navsim'}" in capsys.readouterr().err


def test_a_tagged_column_reads_the_scores_of_its_tagged_subset_only(tmp_path):
    """`lead-s2r score --tag` writes a second scores.json of the same metric; a column with `tag:` reads it, a
    column without one the whole set's, and neither is "two scores.json for one metric"."""
    root = tmp_path / "runs"
    for seed, (whole, subset) in enumerate(((7.0, 5.0), (7.2, 5.5), (7.4, 6.0))):
        run = make_run(root, "wod/ltfv6", seed, {RFS: {"rfs": whole}})
        (run / "tagged").mkdir()
        report = {"metric": RFS, "tag": "cluster:Pedestrian", "aggregates": {"rfs": subset}}
        (run / "tagged" / "scores.json").write_text(json.dumps(report))
    spec = {
        "title": "t",
        "columns": [
            {"name": "RFS", "metric": RFS, "key": "rfs"},
            {"name": "RFS, needs perception", "metric": RFS, "key": "rfs", "tag": "cluster:Pedestrian"},
            {"name": "RFS, cyclists", "metric": RFS, "key": "rfs", "tag": "cluster:Cyclist"},
        ],
        "rows": [{"name": "LTFv6", "run": "wod/ltfv6"}],
    }
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(spec))
    cells = collect(load_spec(tmp_path / "spec.yaml"), find_runs([str(root / "*" / "*" / "seed*")]))[0]
    assert [cell.values for cell in cells] == [(7.0, 7.2, 7.4), (5.0, 5.5, 6.0), ()]


def _edited_spec(folder: Path, path: tuple[Any, ...], value: Any) -> Path:
    """write_spec's table with the field at ``path`` (keys and indices) set to ``value``."""
    spec = yaml.safe_load(write_spec(folder).read_text())
    node = spec
    for name in path[:-1]:
        node = node[name]
    node[path[-1]] = value
    (folder / "table4.yaml").write_text(yaml.safe_dump(spec))
    return folder / "table4.yaml"


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("digits",), "x", r"the spec\.digits is 'x'"),  # was int("x"): a ValueError traceback
        (("seeds",), ["a"], r"the spec\.seeds is \['a'\]"),
        (("title",), None, r"the spec\.title is None"),
        (("columns", 0), 7, r"columns\[0\] is 7, not a mapping"),
        (("columns", 0, "name"), 7, r"columns\[0\]\.name is 7"),  # was printed as a column named 7
        (("rows", 1, "paper"), {}, r"rows\[1\]\.paper is \{\}"),  # was read as no paper numbers
        (("rows", 1, "paper"), [True, None], r"row .LTFv6 \+ LEAD.: paper numbers are numbers"),  # was printed as 1.00
        (("rows", 1, "seeds"), [0.5], r"rows\[1\]\.seeds is \[0\.5\]"),
    ],
)
def test_a_wrong_typed_spec_field_is_named(tmp_path, path, value, message):
    with pytest.raises(TableError, match=r"table4\.yaml: " + message):
        load_spec(_edited_spec(tmp_path, path, value))


def test_a_spec_that_is_not_utf8_is_named(tmp_path):
    (tmp_path / "table4.yaml").write_bytes(b"title: \xff\n")
    with pytest.raises(TableError, match=r"table4\.yaml: cannot read table spec"):
        load_spec(tmp_path / "table4.yaml")


@pytest.mark.parametrize(
    ("report", "message"),
    [
        (b'{"metric": 7, "aggregates": {}}', "metric is 7, not str"),  # was the key 7: a seed missing
        (b'{"metric": "m", "aggregates": "x"}', "aggregates is 'x', not dict"),
        (b"[]", "the file is \\[\\], not a mapping"),  # was an AttributeError
        (b'{"metric": "\xff"}', "cannot read it \\('utf-8' codec"),
        (
            json.dumps({"metric": B2D, "aggregates": {"infractions_per_100km": 7}}).encode(),
            r"aggregates\.infractions_per_100km is 7, not a mapping",
        ),
        (
            json.dumps({"metric": B2D, "aggregates": {"infractions_per_100km": {"red_light": "x"}}}).encode(),
            r"aggregates\.infractions_per_100km\.red_light is .x., not a number",
        ),
    ],
)
def test_a_damaged_scores_json_is_named(tmp_path, runs, report, message):
    """A value that is no number, or no mapping where the column's key goes on, was a seed marked missing."""
    (runs / "wod" / "ltfv6" / "seed1" / "scores1" / "scores.json").write_bytes(report)
    with pytest.raises(TableError, match=r"seed1/scores1/scores\.json: " + message):
        build_table(write_spec(tmp_path), [str(runs / "*" / "*" / "seed*")])


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (b"[1, 2]", "holds \\[1, 2\\], not the mapping"),
        (b"seed_everything: 0\ntrainer: 7\n", "trainer.default_root_dir is not set"),
    ],
)
def test_a_damaged_saved_config_is_named(tmp_path, config, message):
    """A run folder not named seed<k> takes its identity from the config: a list or a trainer of 7 crashed."""
    logs = tmp_path / "somewhere" / "lightning_logs" / "version_0"
    logs.mkdir(parents=True)
    (logs / "config.yaml").write_bytes(config)
    with pytest.raises(TableError, match=r"config\.yaml: " + message):
        find_runs([str(tmp_path / "somewhere")])
