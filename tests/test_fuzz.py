"""Fuzz: one random corruption per trial of small raw data of every adapter, or of a converted folder, run in-process
through ``convert`` / ``read_samples`` / ``inspect`` / ``score``; every trial must keep the contract.

The contract: an error is a :class:`UserError` (one line, naming the file) or, in ``convert``, an errors.jsonl line
naming the file; never another exception. No sample goes missing without a report, and logs whose files were not
touched convert exactly as before. ``LEAD_S2R_FUZZ_TRIALS`` sets the number of trials per target (default 30:
240 trials, about 35 s for the eight targets); ``LEAD_S2R_FUZZ_SEED`` the seed. The py123d targets need py123d's writers
(``lead_s2r.synthetic.py123d``) and are skipped without them.
"""

import json
import os
from collections import Counter
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from corruptions import KINDS, corrupt, hardlink_copy, pick_file

from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.registry import Adapter, get_adapter
from lead_s2r.report.inspection import inspect_dataset
from lead_s2r.scoring.run import planner_predictions, score_predictions
from lead_s2r.shards import ERRORS, load_manifest, read_samples

TRIALS = int(os.environ.get("LEAD_S2R_FUZZ_TRIALS", "30"))
SEED = int(os.environ.get("LEAD_S2R_FUZZ_SEED", "0"))
RAW = ("carla_lead", "navsim", "wod_e2e", "py123d")
#: per adapter: the raw folder, its conversion and the keys of every log
Made = tuple[Path, Path, dict[str, set[str]]]


def _generate(name: str, out: Path) -> None:
    if name == "carla_lead":
        from lead_s2r.synthetic.carla_lead import generate

        generate(out, count=2, seed=3, frames=4)
    elif name == "navsim":
        from lead_s2r.synthetic.navsim import generate

        generate(out, count=2, seed=3)
    elif name == "py123d":  # every reader: a nuPlan-style log with IPC LiDAR and its map, a LEAD one with LAZ LiDAR
        from lead_s2r.synthetic import py123d

        py123d.write_log(out, "log-ipc", index=0, frames=6)  # 43 iterations: 3 samples with a 4 s future
        py123d.write_lead_log(out, index=1, frames=6)
    else:
        from lead_s2r.synthetic.wod_e2e import generate

        generate(out, seed=3, splits={"train": 1, "val": 2})  # test segments have no future to score


def _adapter(name: str, src: Path) -> Adapter:
    """The adapter with every reader on: NAVSIM with its maps and scene filter (GeoPackage and yaml are read too)."""
    if name == "navsim":
        return get_adapter(name, maps=str(src / "maps"), scene_filter=str(src / "scene_filters" / "navmini.yaml"))
    return get_adapter(name)


def _keys_by_log(folder: Path) -> dict[str, set[str]]:
    by_log: dict[str, set[str]] = {}
    for row in load_manifest(folder).select(["log", "key"]).to_pylist():
        by_log.setdefault(row["log"], set()).add(row["key"])
    return by_log


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Callable[[str], Made]:
    """Per adapter, made when a target first asks for it (a skipped target makes nothing)."""
    root = tmp_path_factory.mktemp("fuzz")

    @cache
    def made(name: str) -> Made:
        _generate(name, root / name)
        result = convert(_adapter(name, root / name), root / name, root / f"{name}-out", shard_size=8)
        assert result.ok, result.errors
        return root / name, root / f"{name}-out", _keys_by_log(root / f"{name}-out")

    return made


def _weight(path: Path) -> float:
    """Files of which a dataset holds one or a few (scene filters, cluster maps, manifests) are drawn as often as
    a kind of which it holds hundreds (camera JPEGs), so every reader is hit; 123D's one map as often as each of
    its logs' two files of a modality."""
    if path.suffix in (".jpg", ".png", ".pcd"):
        return 0.05
    if path.suffix == ".arrow" and path.parent.parent.name == "maps":
        return 2.0
    return 1.0


def _names_file(message: str, target: Path) -> bool:
    return target.name in message or target.parent.name in message


def raw_trial(name: str, made: Made, trial: Path, rng: np.random.Generator) -> str:
    """Corrupt one raw file, convert, and check the contract; returns the outcome."""
    pristine_src, _, before = made
    src, out = trial / "src", trial / "out"
    hardlink_copy(pristine_src, src)
    target = pick_file(src, rng, _weight)
    what = corrupt(target, KINDS[int(rng.integers(len(KINDS)))], rng)
    try:  # a bad scene filter is found by the adapter's constructor
        result = convert(_adapter(name, src), src, out, shard_size=8)
    except UserError as err:
        assert _names_file(str(err), target) or str(src) in str(err), f"{what}: {err}"
        return "user error"
    reports = (out / ERRORS).read_text() + json.dumps(result.skipped)
    after = _keys_by_log(out) if result.samples or result.logs_resumed else {}
    for log, keys in before.items():
        if target.parent.name == "scene_filters":  # a filter cut at a line end is a shorter filter: fewer scenes
            assert after.get(log, set()) <= keys, f"{what}: log {log} gained samples"
        elif after.get(log) != keys:
            assert log in reports or target.name in reports, f"{what}: log {log} lost samples, unreported"
    if not result.ok:
        assert _names_file(reports, target), f"{what}: errors.jsonl does not name the file: {reports}"
    if result.samples:
        check_converted(out, sum(len(keys) for keys in after.values()))
    return "reported" if not result.ok else "converted"


def check_converted(folder: Path, count: int) -> None:
    """A folder convert wrote reads back whole: every listed sample, a full inspection."""
    assert sum(1 for _ in read_samples(folder)) == count
    report = inspect_dataset(folder)
    assert report["samples"] == report["checked"] == count and not report["invalid"]


def converted_trial(name: str, made: Made, trial: Path, rng: np.random.Generator) -> str:
    """Corrupt one file of a converted folder, then read, inspect and score it: the whole data or a UserError.

    A flipped bit inside an array changes a value and nothing else (shards carry no checksums); where the value breaks
    the schema, ``inspect`` lists the sample as invalid, and scoring it may fail naming the sample instead of the file.
    """
    _, pristine_out, before = made
    folder = trial / "data"
    hardlink_copy(pristine_out, folder)
    target = pick_file(folder, rng)
    what = corrupt(target, KINDS[int(rng.integers(len(KINDS)))], rng)
    expected = set().union(*before.values())
    outcomes, invalid = [], []
    for step in ("read", "inspect", "score"):
        try:
            if step == "read":
                keys = {sample["__key__"] for sample in read_samples(folder)}
                assert keys == expected, f"{what}: read {len(keys)} of {len(expected)} samples without an error"
            elif step == "inspect":
                report = inspect_dataset(folder)
                assert report["checked"] == len(expected), f"{what}: inspect checked {report['checked']}"
                invalid = report["invalid"]
            else:
                predictions = planner_predictions("human", folder, trial / "pred.parquet")
                score_predictions("ade", predictions, [folder], trial / "scores")
            outcomes.append("ok")
        except UserError as err:
            named = _names_file(str(err), target) or str(folder) in str(err)
            assert named or (step == "score" and invalid), f"{what}: {step}: {err}"
            outcomes.append("user error")
    return "/".join(outcomes)


@pytest.mark.parametrize("target", [*RAW, *(f"{name}-converted" for name in RAW)])
def test_every_corruption_keeps_the_contract(target, pristine, tmp_path):
    name = target.removesuffix("-converted")
    if name == "py123d":
        pytest.importorskip("py123d", reason="py123d is installed with --no-deps in CI (docs/datasets/py123d.md)")
    rng = np.random.default_rng([SEED, RAW.index(name), target.endswith("-converted")])
    outcomes: Counter[str] = Counter()
    for trial in range(TRIALS):
        folder = tmp_path / f"trial{trial}"
        run = converted_trial if target.endswith("-converted") else raw_trial
        outcomes[run(name, pristine(name), folder, rng)] += 1
    print(target, dict(outcomes))
