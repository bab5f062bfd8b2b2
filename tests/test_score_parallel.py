"""``lead-s2r score --workers 2`` and ``--executor ray`` (a real two-node Ray cluster on this machine) write the
bytes one process writes: PDMS and EPDMS on converted NAVSIM data, RFS on WOD-E2E; the reference cache is shared; the
samples, decoded by the workers in parts of a shard, are the ones one process decodes."""

import json
import pickle
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_pdms_navsim import convert_cruise_and_turn

from lead_s2r.cli import main
from lead_s2r.convert import convert
from lead_s2r.predictions import write_predictions
from lead_s2r.processes import InlineExecutor, Job
from lead_s2r.scoring import run
from lead_s2r.scoring.baselines import predict_constant_velocity
from lead_s2r.scoring.navsim import PDMSScorer
from lead_s2r.scoring.run import choose_samples, planner_predictions
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import wod_e2e
from lead_s2r_adapters.wod_e2e import WodE2EAdapter

ray = pytest.importorskip("ray")
from ray.cluster_utils import Cluster  # noqa: E402
from ray_cluster import two_node_cluster  # noqa: E402


@pytest.fixture(scope="module")
def cluster() -> Iterator[Cluster]:
    with two_node_cluster() as cluster:
        yield cluster


@pytest.fixture(scope="module")
def navsim_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two NAVSIM logs (a cruise and a turn, 14 samples) converted with maps, and the constant-velocity
    planner's predictions (it leaves the road in the turn: scores vary)."""
    out = convert_cruise_and_turn(tmp_path_factory.mktemp("navsim_raw"), tmp_path_factory.mktemp("navsim_out"))
    return out, planner_predictions("constant-velocity", out, out.parent / "navsim_predictions.parquet")


@pytest.fixture(scope="module")
def wod_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    raw, out = tmp_path_factory.mktemp("wod_raw"), tmp_path_factory.mktemp("wod_out")
    wod_e2e.generate(raw, count=3, seed=2)
    assert convert(WodE2EAdapter(), raw, out).ok
    wod_grid = np.arange(1, 21, dtype=np.float32) * 0.25  # WOD-E2E's 5 s at 4 Hz: the constant-velocity planner
    predictions = [predict_constant_velocity(sample, wod_grid) for sample in read_samples(out, fields=())]
    return out, write_predictions(out.parent / "wod_predictions.parquet", predictions)


def score(metric: str, data: tuple[Path, Path], out: Path, *options: str) -> dict[str, bytes]:
    """Every file ``score`` writes, by name; scores.json without its ``seconds``."""
    folder, predictions = data
    args = ["score", "--metric", metric, "--predictions", str(predictions), "--data", str(folder), "--out", str(out)]
    assert main([*args, *options]) == 0
    files = {path.name: path.read_bytes() for path in sorted(out.iterdir())}
    report = json.loads(files["scores.json"])
    assert report["seconds"] > 0
    files["scores.json"] = json.dumps({**report, "seconds": None}).encode()
    return files


@pytest.mark.parametrize(
    ("metric", "dataset", "headline"),
    [
        ("pdms@navsim-1.1", "navsim", "pdms"),
        ("epdms@navsim-2.2", "navsim", "epdms"),
        ("rfs@wod-e2e-2025", "wod", "rfs"),
    ],
)
def test_two_processes_and_ray_write_the_bytes_of_one(cluster, request, tmp_path, metric, dataset, headline):
    data = request.getfixturevalue(f"{dataset}_data")
    one = score(metric, data, tmp_path / "one")
    aggregates = json.loads(one["scores.json"])["aggregates"]
    assert aggregates[headline] is not None and aggregates["frames"] >= 3
    assert score(metric, data, tmp_path / "two", "--workers", "2") == one
    assert score(metric, data, tmp_path / "ray", "--executor", "ray", "--address", cluster.address) == one


def test_workers_share_the_reference_cache(navsim_data, tmp_path):
    """Two workers plan into one cache folder; a later run reads the references and scores the same."""
    cache = tmp_path / "cache"
    two = score("pdms@navsim-1.1", navsim_data, tmp_path / "two", "--workers", "2", "--reference-cache", str(cache))
    references = sorted(cache.iterdir())
    assert len(references) == 14 and all(path.suffix == ".npy" for path in references)  # no partial file left
    one = score("pdms@navsim-1.1", navsim_data, tmp_path / "one", "--reference-cache", str(cache))
    assert one == two


class CountingExecutor(InlineExecutor):
    """This process, counting the jobs it is given."""

    jobs = 0

    def run(self, job: Job, arguments: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        self.jobs += len(arguments)
        return super().run(job, arguments)


def test_samples_decoded_in_parts_are_the_samples_one_process_decodes(navsim_data, monkeypatch):
    folder, _ = navsim_data
    whole = list(read_samples(folder, fields=PDMSScorer.fields))  # one process, webdataset's reader
    monkeypatch.setattr(run, "SAMPLES_PER_READ", 4)
    executor = CountingExecutor()
    parts = choose_samples([folder], PDMSScorer.fields, None, executor)[0]
    assert executor.jobs == 4  # 14 samples of one shard in parts of 4
    assert pickle.dumps(parts) == pickle.dumps(whole)  # the same samples, fields and arrays, in the same order
