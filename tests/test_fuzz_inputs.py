"""Fuzz of the files users hand us besides raw data: one random corruption (tests/corruptions.py) per trial of a
predictions file, a LEAD checkpoint folder, the closed-loop agent's config, leaderboard results and routes, a table's
spec and runs, a scored run folder, a LightningCLI config, the run folder the CARLA agent drives (``closed-loop
check``) and a run folder export-lead reads, each read through the public function or verb that takes it.

The contract (as tests/test_fuzz.py's): the call gives the pristine result, or raises :class:`UserError` naming the
file (a verb: exit status 2 and one ``error:`` line on stderr naming it, after any library warning); never another
exception. A different result is allowed only where the reader cannot know: a byte changed inside a value of a text
file (a digit of a number), a line-based file (YAML, CSV) cut at a line, a value replaced by null or by another of
its own type, a null by a number or text, what a report shows as it is (the saved config, aggregates), and a deleted
training log. A table whose scores.json was deleted must list that seed as missing. ``LEAD_S2R_FUZZ_TRIALS`` sets the
trials per target (default 12: about 20 s for the first nine targets, and a minute for the agent's run folder);
``LEAD_S2R_FUZZ_SEED`` the seed.
"""

import contextlib
import io
import json
import os
import re
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
import yaml
from corruptions import KINDS, corrupt, hardlink_copy, pick_file
from lead_reference import TINY_NAVSIM
from test_carla_leaderboard import VEHICLE_HIT, off_lane, record, results_file, slow
from test_lead_checkpoints import lead_run
from test_tables import make_run, write_spec
from test_user_errors import fit_config

from lead_s2r import cli
from lead_s2r.closed_loop.agent import ClosedLoopConfig
from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.models import lead
from lead_s2r.predictions import regular_grid, write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.report.run_outputs import load_run
from lead_s2r.scoring.baselines import predict_constant_velocity
from lead_s2r.scoring.run import SampleCache, score_predictions
from lead_s2r.shards import read_samples
from lead_s2r.submit import navsim as navsim_submit
from lead_s2r.submit import wod_e2e as wod_submit
from lead_s2r.synthetic import navsim as navsim_synth
from lead_s2r.synthetic import wod_e2e as wod_synth
from lead_s2r.training import cli as training_cli  # noqa: F401 - Lightning's log handler binds at collection

TRIALS = int(os.environ.get("LEAD_S2R_FUZZ_TRIALS", "12"))
SEED = int(os.environ.get("LEAD_S2R_FUZZ_SEED", "0"))
TINY_LEAD = Path(__file__).parent / "data" / "lead_tfv6" / "tiny_ltfv6_navsim" / "config.json"
NAVSIM_METADATA = navsim_submit.NavsimMetadata("fuzz", "A. Driver", "a@b.c", "Uni", "DE")
WOD_METADATA = wod_submit.WodMetadata("a@b.c", "m", ["A. Driver"], "1K", False)
#: Corruptions that may change a value of a text file and leave it valid: the reader cannot know.
VALUE_CHANGES = ("flip", "zero_span", "random_span")
LINE_FORMATS = (".yaml", ".csv")
TARGETS = (
    "predictions-navsim",
    "predictions-wod",
    "lead-checkpoint",
    "agent-config",
    "carla-metrics",
    "table",
    "report",
    "fit",
    "closed-loop-check",
    "export-lead",
)
#: An agent config YAML of the closed-loop agent (the leaderboard's --agent-config) with a field of every type.
AGENT_CONFIG = {
    "checkpoint": "runs/a/seed0",
    "controller": "waypoint",
    "rig": None,
    "creeping": True,
    "jpeg_quality": 80,
}


#: What a report shows as it is: its saved config, the aggregates of a scores.json (any value of any metric); and
#: what it may lack: training logs, the config.
SHOWN_AS_IS = ("config.yaml",)
OPTIONAL = ("metrics.csv", "config.yaml")


def _may_change(kind: str, target: Path, pristine: Path, shown_as_is: bool = False) -> bool:
    """Whether a different result is no defect: a changed byte of a text value, a line format cut at a line, a value
    replaced by null or by another of its own type (``"n": 7`` for ``"n": 2``), a null by a number or text, or what a
    report shows as it is."""
    if shown_as_is and (target.name in SHOWN_AS_IS or (kind == "delete" and target.name in OPTIONAL)):
        return True
    if kind == "wrong_type" and target.suffix in (".json", ".yaml"):
        where, old, new = _replaced(pristine, target)
        shown = shown_as_is and target.name == "scores.json" and where[:1] == ["aggregates"]
        nullable = old is None and _json_type(new) in ("number", "str")  # e.g. the leaderboard's own DS, if any
        return shown or nullable or new is None or _json_type(old) == _json_type(new)
    text = target.suffix in (".json", ".xml", *LINE_FORMATS)
    return text and (kind in VALUE_CHANGES or (kind == "truncate" and target.suffix in LINE_FORMATS))


def _json_type(value: Any) -> str:
    return "number" if isinstance(value, int | float) and not isinstance(value, bool) else type(value).__name__


def _replaced(pristine: Path, corrupted: Path) -> tuple[list[Any], Any, Any]:
    """Where a wrong_type corruption replaced a value of a JSON or YAML file (keys and indices), the value and what
    it put there."""
    load = json.loads if pristine.suffix == ".json" else yaml.safe_load
    old, new = (load(path.read_bytes()) for path in (pristine, corrupted))
    where: list[Any] = []
    while type(old) is type(new) and isinstance(old, dict | list) and len(old) == len(new):
        keys = list(old) if isinstance(old, dict) else range(len(old))
        if keys != (list(new) if isinstance(new, dict) else keys):  # a mapping put in place of another
            break
        key = next(key for key in keys if old[key] != new[key])
        where.append(key)
        old, new = old[key], new[key]
    return where, old, new


def _detail(kind: str, target: Path, pristine: Path) -> str:
    """For a failure message: where a wrong_type corruption replaced a value, the value and by what."""
    return " (at {} {!r} -> {!r})".format(*_replaced(pristine, target)) if kind == "wrong_type" else ""


def _names(message: str, target: Path) -> bool:
    return target.name in message or target.parent.name in message


def keeps_contract(call: Callable[[], Any], expected: Any, trial: tuple, pristine: Path) -> str:
    """Run ``call`` on the corrupted input of ``trial`` (from :func:`corrupt_one`); returns the outcome, fails on a
    broken contract."""
    folder, target, kind, what = trial
    try:
        result = call()
    except UserError as err:
        assert _names(str(err), target), f"{what}: the error does not name the file: {err}"
        return "user error"
    if result == expected:
        return "same"
    original = pristine / target.relative_to(folder)
    assert _may_change(kind, target, original), f"{what}{_detail(kind, target, original)}: a different result, no error"
    return "changed"


def corrupt_one(pristine: Path, trial: Path, rng: np.random.Generator, keep: Callable[[Path], bool] = bool) -> tuple:
    """A hard-linked copy of ``pristine`` with one file (of those ``keep`` accepts) corrupted: (copy, file, kind,
    what was done)."""
    folder = trial / pristine.name
    hardlink_copy(pristine, folder)
    target = pick_file(folder, rng, lambda path: float(keep(path)))
    kind = KINDS[int(rng.integers(len(KINDS)))]
    what = corrupt(target, kind, rng)
    if kind == "wrong_type" and not what.startswith("one value"):  # not a structured file: corrupt flipped bits
        kind = "flip"
    return folder, target, kind, what


def _converted(name: str, root: Path) -> Path:
    raw, out = root / f"{name}-raw", root / f"{name}-data"
    if name == "navsim":
        navsim_synth.generate(raw, count=1, seed=3)
        adapter = get_adapter("navsim", maps=str(raw / "maps"))
    else:
        wod_synth.generate(raw, count=1, seed=3)
        adapter = get_adapter("wod_e2e")
    assert convert(adapter, raw, out, progress=False).ok
    return out


def _scored(metrics: tuple[str, ...], predictions: Path, data: Path, out: Path, cache: SampleCache) -> list[dict]:
    """The aggregates and unpredicted samples of each metric: what a corruption must not change silently."""
    results = []
    for metric in metrics:
        report = score_predictions(metric, predictions, [data], out / metric, sample_cache=cache, allow_missing=True)
        results.append({"aggregates": report["aggregates"], "unpredicted": report["unpredicted"]})
    return results


def _submitted(dataset: str, predictions: Path, data: Path, out: Path) -> bytes:
    if dataset == "navsim":
        navsim_submit.write_navsim(out / "submission.pkl", NAVSIM_METADATA, [predictions], [data])
        return (out / "submission.pkl").read_bytes()
    wod_submit.write_wod(out / "submission", WOD_METADATA, predictions, [data])
    return b"".join(path.read_bytes() for path in sorted((out / "submission").iterdir()))


@pytest.fixture(scope="module")
def predictions(tmp_path_factory) -> dict[str, tuple[Path, Path, SampleCache, tuple]]:
    """Per dataset: its converted folder, a predictions folder (constant velocity for every sample), the decoded
    samples, and the pristine scores and submission."""
    root = tmp_path_factory.mktemp("fuzz_predictions")
    made = {}
    for dataset, metrics in (("navsim", ("ade", "pdms@navsim-1.1")), ("wod_e2e", ("rfs@wod-e2e-2025",))):
        data = _converted(dataset, root)
        grid = regular_grid(2, 4) if dataset == "navsim" else regular_grid(4, 5)
        folder = root / f"{dataset}-predictions"
        folder.mkdir()
        rows = (predict_constant_velocity(sample, grid) for sample in read_samples(data, fields=("meta",)))
        path = write_predictions(folder / "predictions.parquet", rows)
        cache = SampleCache()
        expected = (
            _scored(metrics, path, data, root / dataset, cache),
            _submitted(dataset, path, data, root / dataset),
        )
        made[dataset] = (data, folder, cache, (metrics, expected))
    return made


def predictions_trial(made: tuple, trial: Path, rng: np.random.Generator) -> str:
    """Corrupt predictions.parquet, then score it and write the dataset's submission."""
    data, pristine, cache, (metrics, expected) = made
    corrupted = corrupt_one(pristine, trial, rng)
    dataset = "navsim" if "navsim" in metrics[-1] else "wod_e2e"
    target = corrupted[1]

    def run() -> tuple:
        scores = _scored(metrics, target, data, trial / "scores", cache)
        return scores, _submitted(dataset, target, data, trial / "submission")

    return keeps_contract(run, expected, corrupted, pristine)


def _state(model: torch.nn.Module) -> dict[str, bytes]:
    return {name: tensor.numpy().tobytes() for name, tensor in model.state_dict().items()}


@pytest.fixture(scope="module")
def lead_checkpoint(tmp_path_factory) -> tuple[Path, dict[str, bytes]]:
    """A tiny LEAD checkpoint folder as export_checkpoint writes it, and its weights."""
    folder = tmp_path_factory.mktemp("fuzz_lead") / "checkpoint"
    torch.manual_seed(0)
    lead.export_checkpoint(lead.model_from_config(json.loads(TINY_LEAD.read_text())), folder)
    return folder, _state(lead.load_checkpoint(folder))


def checkpoint_trial(made: tuple, trial: Path, rng: np.random.Generator) -> str:
    pristine, expected = made
    corrupted = corrupt_one(pristine, trial, rng)
    return keeps_contract(lambda: _state(lead.load_checkpoint(corrupted[0])), expected, corrupted, pristine)


@pytest.fixture(scope="module")
def agent_config(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz_agent") / "agent"
    folder.mkdir()
    (folder / "drive.yaml").write_text(yaml.safe_dump(AGENT_CONFIG))
    return folder


def agent_config_trial(pristine: Path, trial: Path, rng: np.random.Generator) -> str:
    corrupted = corrupt_one(pristine, trial, rng)
    expected = ClosedLoopConfig.from_agent_config(str(pristine / "drive.yaml"), {})
    read = lambda: ClosedLoopConfig.from_agent_config(str(corrupted[0] / "drive.yaml"), {})  # noqa: E731
    return keeps_contract(read, expected, corrupted, pristine)


@pytest.fixture(scope="module")
def leaderboard_results(tmp_path_factory) -> Path:
    """Two results files of Town13 routes (a hit, an off-lane stretch, a slow drive) and its routes XML."""
    folder = tmp_path_factory.mktemp("fuzz_results") / "results"
    folder.mkdir()
    results_file(folder, [record(0, infractions={"collisions_vehicle": [VEHICLE_HIT]}), record(1, rc=62.5)], "a.json")
    off_lane_record = record(2, infractions={"outside_route_lanes": [off_lane(12.5, 3.1)]})
    slow_record = record(3, length=700.0, infractions={"min_speed_infractions": [slow(62.5)]})
    results_file(folder, [off_lane_record, slow_record], "b.json")
    routes = "".join(f'<route id="{i}" town="Town13"/>' for i in range(6))
    (folder / "routes.xml").write_text(f"<routes>{routes}</routes>")
    return folder


def _carla_argv(folder: Path, out: Path) -> list[str]:
    results = [str(folder / name) for name in ("a.json", "b.json")]
    return [
        "carla-metrics",
        *results,
        "--benchmark",
        "town13",
        "--out",
        str(out),
        "--routes",
        str(folder / "routes.xml"),
    ]


@pytest.fixture(scope="module")
def table_runs(tmp_path_factory) -> Path:
    """A table spec and three seeds of two runs, as test_tables lays them out."""
    root = tmp_path_factory.mktemp("fuzz_table") / "table"
    scores = {"rfs@wod-e2e-2025": {"rfs": 7.5}, "carla-leaderboard-2.0/bench2drive": {"infractions_per_100km": {}}}
    for seed, rfs, red in ((0, 7.5, 1.0), (1, 7.7, 2.0), (2, 7.9, 6.0)):
        scores["rfs@wod-e2e-2025"]["rfs"] = rfs
        scores["carla-leaderboard-2.0/bench2drive"]["infractions_per_100km"] = {"red_light": red}
        make_run(root / "runs", "wod/ltfv6", seed, scores)
        make_run(root / "runs", "wod/ltfv6_lead", seed, {"rfs@wod-e2e-2025": {"rfs": rfs - 0.5}})
    write_spec(root)
    return root


def _table_argv(folder: Path) -> list[str]:
    return ["table", "--spec", str(folder / "table4.yaml"), "--runs", str(folder / "runs" / "*" / "*" / "seed*")]


@pytest.fixture(scope="module")
def scored_run(tmp_path_factory, predictions) -> tuple[Path, Path]:
    """A scored run folder (ADE of the NAVSIM predictions, a training log and config) and its converted data."""
    data, folder, cache, _ = predictions["navsim"]
    run = tmp_path_factory.mktemp("fuzz_report") / "run"
    score_predictions("ade", folder / "predictions.parquet", [data], run / "ade", sample_cache=cache)
    (run / "predictions.parquet").hardlink_to(folder / "predictions.parquet")
    logs = run / "lightning_logs" / "version_0"
    logs.mkdir(parents=True)
    (logs / "metrics.csv").write_text("epoch,step,train/loss,val/ade\n0,1,2.5,\n0,2,1.5,\n0,2,,0.75\n")
    (logs / "config.yaml").write_text(yaml.safe_dump({"seed_everything": 0, "trainer": {"max_epochs": 1}}))
    return run, data


def _report_argv(run: Path, data: Path, out: Path, key: str) -> list[str]:
    return ["report", str(run), "--out", str(out), "--data", str(data), "--samples", key]


@pytest.fixture(scope="module")
def fit_yaml(tmp_path_factory) -> Path:
    """A fit config of a tiny model whose data folder does not exist: every trial parses and instantiates the
    config (where a bad value is found) and, when the config is whole, stops at the data before training."""
    root = tmp_path_factory.mktemp("fuzz_fit")
    path = fit_config(root, {"carla": {"paths": [str(root / "no-data")], "cameras": ["front"]}})
    folder = root / "config"
    folder.mkdir()
    path.rename(folder / "fit.yaml")
    return folder


@pytest.fixture(scope="module")
def agent_run(tmp_path_factory) -> Path:
    """The run folder the CARLA agent drives (its config.yaml and checkpoints): a tiny TFv6 fitted for 2 steps on a
    synthetic LEAD route, as tests/test_closed_loop_agent.py makes it, checked as ``lead-s2r closed-loop check``."""
    pytest.importorskip("carla", reason="the CARLA client (pip install 'lead-s2r[carla]') builds CARLA's types")
    from test_closed_loop_agent import MODEL
    from test_closed_loop_agent import fit_config as agent_fit_config

    from lead_s2r.synthetic import carla_lead as carla_synth
    from lead_s2r.training.cli import run_lightning_cli

    root = tmp_path_factory.mktemp("fuzz_agent_run")
    carla_synth.generate(root / "src", count=1, frames=4)
    assert convert(get_adapter("carla_lead"), root / "src", root / "data", shard_size=8, progress=False).ok
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:  # fit's summary kept out of the output the first trial compares (the fixture runs inside the test)
        with contextlib.redirect_stdout(io.StringIO()):
            run_lightning_cli(["fit", "--config", str(agent_fit_config(root / "run", root / "data", MODEL, steps=2))])
    finally:
        torch.set_num_threads(threads)
    return root / "run"


@pytest.fixture(scope="module")
def lead_run_folder(tmp_path_factory) -> Path:
    """A run folder of the smoke recipe's tiny NAVSIM LTFv6 (seeded weights) with the config LightningCLI saves."""
    run = lead_run(tmp_path_factory.mktemp("fuzz_export") / "run", TINY_NAVSIM)
    (run / "config.yaml").write_text(yaml.safe_dump({"seed_everything": 0, "trainer": {"max_epochs": 1}}))
    return run


def _verb(target: str, request: Any) -> tuple[Path, Callable[[Path, Path], list[str]]]:
    """The pristine input folder of a verb target and its command line for an input folder and an output folder."""
    if target == "carla-metrics":
        return request.getfixturevalue("leaderboard_results"), lambda folder, out: _carla_argv(folder, out)
    if target == "table":
        return request.getfixturevalue("table_runs"), lambda folder, out: _table_argv(folder)
    if target == "report":
        run, data = request.getfixturevalue("scored_run")
        key = sorted(load_run(run).scores[0].rows)[0]
        return run, lambda folder, out: _report_argv(folder, data, out, key)
    if target == "closed-loop-check":
        return request.getfixturevalue("agent_run"), lambda folder, out: ["closed-loop", "check", str(folder)]
    if target == "export-lead":
        return request.getfixturevalue("lead_run_folder"), lambda folder, out: [
            "export-lead",
            str(folder),
            "--out",
            str(out),
        ]
    return request.getfixturevalue("fit_yaml"), lambda folder, out: ["fit", "--config", str(folder / "fit.yaml")]


def _verb_output(argv: list[str], folder: Path, out: Path, capsys: Any) -> tuple[int, str, str]:
    """Exit status, stderr and what the verb wrote (stdout, and the text and tables of its output folder), with the
    input and output folders' paths named alike in every trial."""
    status = cli.main(argv)
    captured = capsys.readouterr()
    written = sorted(path for path in out.rglob("*") if path.suffix in (".json", ".html", ".parquet", ".pth"))
    output = captured.out + "".join(_content(path) for path in written)
    return status, captured.err.replace(str(folder), "IN"), output.replace(str(folder), "IN").replace(str(out), "OUT")


def _content(path: Path) -> str:
    if path.suffix == ".pth":  # exported weights: each tensor's bytes
        return str({name: tensor.numpy().tobytes() for name, tensor in torch.load(path, weights_only=True).items()})
    return str(pq.read_table(path).to_pylist()) if path.suffix == ".parquet" else path.read_text()


def verb_trial(target: str, request: Any, trial: Path, rng: np.random.Generator, capsys: Any, expected: tuple) -> str:
    """Corrupt one input of the verb, run it: exit 0 with the pristine output, the pristine error, or exit 2 and
    one stderr line naming the file."""
    pristine, argv = _verb(target, request)
    folder, target_file, kind, what = corrupt_one(pristine, trial, rng)
    status, err, output = _verb_output(argv(folder, trial / "out"), folder, trial / "out", capsys)
    if (status, err, output) == expected:
        return "same"
    if status == 2:  # Lightning's warnings may come first
        lines = [line for line in err.strip().splitlines() if line.startswith("error: ")]
        assert len(lines) == 1 and _names(lines[0], target_file) and "Traceback" not in err, f"{what}: {err}"
        return "user error"
    assert status == 0, f"{what}: exit status {status}: {err}"
    if target == "table" and kind == "delete" and target_file.name == "scores.json":  # that seed was never scored
        seed = target_file.parent.parent.name.removeprefix("seed")
        assert re.search(rf"seeds \[[^]]*\b{seed}\b[^]]*\] missing", output), f"{what}: seed {seed} not missing"
        return "seed missing"
    original = pristine / target_file.relative_to(folder)
    changed = _may_change(kind, target_file, original, shown_as_is=target == "report")
    assert changed, f"{what}{_detail(kind, target_file, original)}: a different output without an error"
    return "changed"


@pytest.mark.parametrize("target", TARGETS)
def test_every_corruption_keeps_the_contract(target, request, tmp_path, capsys, monkeypatch):
    rng = np.random.default_rng([SEED, TARGETS.index(target)])
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI warns when the process has other arguments
    expected = None
    if target not in ("predictions-navsim", "predictions-wod", "lead-checkpoint", "agent-config"):
        pristine, argv = _verb(target, request)
        expected = _verb_output(argv(pristine, tmp_path / "out"), pristine, tmp_path / "out", capsys)
        assert expected[0] == (2 if target == "fit" else 0), expected[1]
    outcomes: Counter[str] = Counter()
    for index in range(TRIALS):
        trial = tmp_path / f"trial{index}"
        trial.mkdir()
        if target.startswith("predictions-"):
            dataset = "navsim" if target.endswith("navsim") else "wod_e2e"
            outcome = predictions_trial(request.getfixturevalue("predictions")[dataset], trial, rng)
        elif target == "lead-checkpoint":
            outcome = checkpoint_trial(request.getfixturevalue("lead_checkpoint"), trial, rng)
        elif target == "agent-config":
            outcome = agent_config_trial(request.getfixturevalue("agent_config"), trial, rng)
        else:
            outcome = verb_trial(target, request, trial, rng, capsys, expected)
        outcomes[outcome] += 1
    with capsys.disabled():
        print(target, dict(outcomes))
