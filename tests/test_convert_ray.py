"""``convert`` on a real Ray cluster of two nodes on this machine (one CPU and 100 MB of object store
each): the bytes of one process for every adapter, a worker killed mid-log, a killed driver resumed."""

import os
import signal
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_convert import digests, keys_in_shards, kill_mid_run
from toy_adapter import ToyAdapter, write_toy_logs

from lead_s2r.cli import main
from lead_s2r.convert import convert, one_thread_per_worker
from lead_s2r.processes import RayExecutor
from lead_s2r.registry import LogRef, load
from lead_s2r.synthetic import carla_lead, navsim, wod_e2e

ray = pytest.importorskip("ray")
from ray.cluster_utils import Cluster  # noqa: E402
from ray_cluster import two_node_cluster  # noqa: E402

TESTS = str(Path(__file__).parent)


@pytest.fixture(scope="module")
def cluster() -> Iterator[Cluster]:
    with two_node_cluster() as cluster:
        yield cluster


def on_ray(cluster: Cluster) -> RayExecutor:
    return RayExecutor(cluster.address, initializer=one_thread_per_worker)


SYNTHETIC = {
    "carla_lead": lambda src: carla_lead.generate(src, count=3, seed=1, frames=3),
    "navsim": lambda src: navsim.generate(src, count=2, seed=1),
    "wod_e2e": lambda src: wod_e2e.generate(src, count=2, seed=1),
}


@pytest.mark.parametrize("name", sorted(SYNTHETIC))
def test_every_adapter_on_ray_writes_the_bytes_of_one_process(cluster, tmp_path, name):
    src = tmp_path / "src"
    SYNTHETIC[name](src)
    adapter = load(name)()
    one = convert(adapter, src, tmp_path / "one", workers=1, shard_size=4)
    on_cluster = convert(adapter, src, tmp_path / "ray", executor=on_ray(cluster), shard_size=4)
    assert one.ok and on_cluster.ok and on_cluster.samples == one.samples > 0
    assert on_cluster.logs_converted == one.logs_converted >= 2
    assert len(digests(tmp_path / "one")) > 4  # several shards, a manifest, info.json...
    assert digests(tmp_path / "ray") == digests(tmp_path / "one")


class DyingToy(ToyAdapter):
    """The Ray worker converting log001 dies (SIGKILL, as the OOM killer or a lost node would) after writing two
    samples, the first time only: ``marker`` records that it happened."""

    def __init__(self, marker: str) -> None:
        super().__init__(sleep=0.01)
        self.marker = marker

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        for frame, sample in enumerate(super().iter_samples(log)):
            if log.log_id == "log001" and frame == 2 and not Path(self.marker).exists():
                Path(self.marker).write_text(str(os.getpid()))
                os.kill(os.getpid(), signal.SIGKILL)
            yield sample


def test_a_worker_killed_mid_log_reruns_that_log(cluster, tmp_path):
    write_toy_logs(tmp_path / "src", n_logs=4, frames=6)
    marker = tmp_path / "died"
    result = convert(DyingToy(str(marker)), tmp_path / "src", tmp_path / "ray", executor=on_ray(cluster), shard_size=5)
    assert marker.exists(), "the worker converting log001 should have been killed"
    assert result.ok and result.samples == 24 and result.logs_converted == 4
    counts = Counter(keys_in_shards(tmp_path / "ray"))
    assert len(counts) == 24 and max(counts.values()) == 1
    assert not list((tmp_path / "ray" / "shards").glob("*.partial"))
    convert(DyingToy(str(marker)), tmp_path / "src", tmp_path / "one", workers=1, shard_size=5)
    assert digests(tmp_path / "ray") == digests(tmp_path / "one")


DRIVER = """
import sys
sys.path.insert(0, {tests!r})
from toy_adapter import ToyAdapter
from lead_s2r.convert import convert
from lead_s2r.processes import RayExecutor
convert(ToyAdapter(sleep=0.05), {src!r}, {out!r}, executor=RayExecutor({address!r}), shard_size=8)
"""


def test_a_killed_driver_resumes_without_loss_or_duplicate(cluster, tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    write_toy_logs(src, n_logs=12, frames=5)
    kill_mid_run(DRIVER.format(tests=TESTS, src=str(src), out=str(out), address=cluster.address), out)
    result = convert(ToyAdapter(), src, out, executor=on_ray(cluster), shard_size=8)
    assert result.ok and result.logs_resumed >= 2
    counts = Counter(keys_in_shards(out))
    assert len(counts) == 60 and max(counts.values()) == 1
    convert(ToyAdapter(), src, tmp_path / "whole", workers=1, shard_size=8)
    assert digests(out) == digests(tmp_path / "whole")


def test_the_cli_converts_on_ray(cluster, tmp_path, capsys):
    carla_lead.generate(tmp_path / "src", count=2, seed=3, frames=2)
    where = ["--src", str(tmp_path / "src"), "--out", str(tmp_path / "out")]
    assert main(["convert", "carla_lead", *where, "--executor", "ray", "--address", cluster.address]) == 0
    assert "4 samples from 2 logs" in capsys.readouterr().out


def test_ray_missing_is_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ModuleNotFoundError
    args = ["convert", "carla_lead", "--src", TESTS, "--out", str(tmp_path / "out"), "--executor", "ray"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "pip install 'lead-s2r[ray]'" in err
    assert not (tmp_path / "out").exists()
    assert main([*args[:-2], "--address", "auto"]) == 2
    assert "--address names a Ray cluster: add --executor ray" in capsys.readouterr().err


def test_results_outlive_the_connection(cluster):
    """Ray hands arrays over as views into its object store, unmapped when the run disconnects: results are copies
    (a second run, as EPDMS makes over the first one's frames, read freed memory)."""
    results = dict(RayExecutor(cluster.address).run(np.full, [((1000, 1000), 7.0), ((10,), 1.0)]))
    assert not ray.is_initialized()  # connected for the run only
    assert results[0].flags.writeable and results[0].shape == (1000, 1000) and float(results[0].sum()) == 7e6
    assert float(results[1].sum()) == 10.0


def test_a_session_keeps_one_connection_over_runs(cluster):
    """``score`` reads the samples, then scores them: two runs in one session connect once."""
    executor = RayExecutor(cluster.address)
    with executor.session():
        first = dict(executor.run(np.full, [((3,), 1.0)]))
        assert ray.is_initialized()  # the run left the session's connection open
        second = dict(executor.run(np.full, [((2,), 5.0)]))
    assert not ray.is_initialized()
    assert first[0].tolist() == [1.0] * 3 and second[0].tolist() == [5.0] * 2
