import hashlib
import json
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from toy_adapter import InterruptedToy, ToyAdapter, write_toy_logs

from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.registry import Adapter, LogRef
from lead_s2r.shards import load_info, load_manifest, read_samples


def keys_in_shards(out: Path) -> list[str]:
    return [s["__key__"] for s in read_samples(out, fields=[])]


def digests(out: Path) -> dict[str, str]:
    """sha256 of every file of a converted folder, by its path in the folder."""
    return {
        str(path.relative_to(out)): hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(out.rglob("*"))
        if path.is_file()
    }


@pytest.mark.parametrize("workers", [1, 2])
def test_every_sample_once_and_manifest_matches(tmp_path, workers):
    write_toy_logs(tmp_path / "src", n_logs=5, frames=7)
    result = convert(ToyAdapter(), tmp_path / "src", tmp_path / "out", workers=workers, shard_size=10)
    assert result.ok and result.samples == 35 and result.logs_converted == 5
    keys = keys_in_shards(tmp_path / "out")
    assert len(keys) == 35 and len(set(keys)) == 35
    manifest = load_manifest(tmp_path / "out")
    assert sorted(manifest["key"].to_pylist()) == sorted(keys)
    # a log never straddles two shards
    shards_per_log = {log: set() for log in manifest["log"].to_pylist()}
    for log, shard in zip(manifest["log"].to_pylist(), manifest["shard"].to_pylist(), strict=True):
        shards_per_log[log].add(shard)
    assert all(len(s) == 1 for s in shards_per_log.values())
    info = load_info(tmp_path / "out")
    assert info["counts"]["samples"] == 35 and info["counts"]["logs"] == 5
    assert info["statistics"]["tp_x"]["max"] == 10.0
    assert manifest["has_lidar"].to_pylist() == [True] * 35


def test_broken_log_is_isolated(tmp_path):
    write_toy_logs(tmp_path / "src", n_logs=6, frames=6, broken=(2,), skipped=(4,))
    result = convert(ToyAdapter(), tmp_path / "src", tmp_path / "out", shard_size=100)
    assert not result.ok
    assert result.samples == 4 * 6
    lines = (tmp_path / "out" / "errors.jsonl").read_text().splitlines()
    assert len(lines) == 1
    error = json.loads(lines[0])
    assert error["log"] == "log002" and "field 'pose'" in error["error"] and "log002.json" in error["error"]
    keys = keys_in_shards(tmp_path / "out")
    assert not any("log002" in k or "log004" in k for k in keys)  # the half-written log was rolled back
    assert len(keys) == 24
    assert load_info(tmp_path / "out")["skipped_logs"] == [{"log": "log004", "reason": "route failed"}]


LENGTHS = [12, 3, 5, 3, 4, 3, 2]  # log000 is the longest: with two workers, later logs finish before it


@pytest.mark.parametrize(
    ("broken", "skipped", "shards"),
    [
        ((), (), {"toy-000000.tar": 12, "toy-000001.tar": 8, "toy-000002.tar": 7, "toy-000003.tar": 5}),
        ((1, 3), (4,), {"toy-000000.tar": 12, "toy-000001.tar": 8, "toy-000002.tar": 2}),
    ],
)
def test_any_number_of_workers_writes_the_same_bytes(tmp_path, broken, skipped, shards):
    write_toy_logs(tmp_path / "src", n_logs=7, frames=LENGTHS, broken=broken, skipped=skipped)
    runs = {}
    for name, workers in (("one", 1), ("two", 2), ("two_again", 2)):
        convert(ToyAdapter(sleep=0.01), tmp_path / "src", tmp_path / name, workers=workers, shard_size=6)
        runs[name] = digests(tmp_path / name)
    assert runs["two"] == runs["one"] and runs["two_again"] == runs["one"]
    # shards close at the first log boundary after 6 samples, in the order of the log list, failed logs left out
    assert load_info(tmp_path / "one")["shards"] == shards
    errors = [json.loads(line)["log"] for line in (tmp_path / "one" / "errors.jsonl").read_text().splitlines()]
    assert errors == [f"log{i:03d}" for i in broken]
    assert sorted(runs["one"]) == sorted(
        [
            "convert.json",
            "errors.jsonl",
            "info.json",
            "manifest.parquet",
            "progress.jsonl",
            *(f"shards/{shard}" for shard in shards),
        ]
    )


def test_an_interrupted_conversion_stops_its_workers(tmp_path):
    write_toy_logs(tmp_path / "src", n_logs=8, frames=40)  # 2 s per log: 14 s of work after log000
    started = time.perf_counter()
    with pytest.raises((KeyboardInterrupt, RuntimeError)):  # the driver's own log, or a worker's that then dies
        convert(InterruptedToy(sleep=0.05), tmp_path / "src", tmp_path / "out", workers=2)
    assert time.perf_counter() - started < 8.0, "the worker should be stopped, not left to finish the logs"
    assert mp.active_children() == []
    assert not (tmp_path / "out" / "manifest.parquet").exists()


def test_rerun_skips_finished_logs_and_force_redoes(tmp_path):
    write_toy_logs(tmp_path / "src", n_logs=3, frames=4)
    convert(ToyAdapter(), tmp_path / "src", tmp_path / "out", shard_size=1)
    again = convert(ToyAdapter(), tmp_path / "src", tmp_path / "out", shard_size=1)
    assert again.logs_converted == 0 and again.logs_resumed == 3
    assert len(load_manifest(tmp_path / "out")) == 12
    forced = convert(ToyAdapter(), tmp_path / "src", tmp_path / "out", shard_size=1, force=True)
    assert forced.logs_converted == 3 and len(keys_in_shards(tmp_path / "out")) == 12


KILLABLE = """
import sys
sys.path.insert(0, {tests!r})
from toy_adapter import ToyAdapter
from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.registry import Adapter, LogRef
convert(ToyAdapter(sleep=0.02), {src!r}, {out!r}, workers={workers}, shard_size=8)
"""


def kill_mid_run(code: str, out: Path, timeout_s: float = 120) -> None:
    """Run a converting driver (Python ``code``) and SIGKILL its process group once two logs are recorded."""
    driver = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        progress = out / "progress.jsonl"
        if progress.exists() and len(progress.read_text().splitlines()) >= 2:
            break
        time.sleep(0.05)
    os.killpg(driver.pid, signal.SIGKILL)
    driver.wait()
    assert not (out / "manifest.parquet").exists(), "the driver should have been killed before finishing"


@pytest.mark.parametrize("workers", [1, 2])
def test_resume_after_kill_loses_and_duplicates_nothing(tmp_path, workers):
    src, out = tmp_path / "src", tmp_path / "out"
    write_toy_logs(src, n_logs=12, frames=5)
    kill_mid_run(KILLABLE.format(tests=str(Path(__file__).parent), src=str(src), out=str(out), workers=workers), out)
    result = convert(ToyAdapter(), src, out, workers=workers, shard_size=8)
    assert result.ok and result.logs_resumed >= 2
    keys = keys_in_shards(out)
    counts = Counter(keys)
    assert len(counts) == 60 and max(counts.values()) == 1
    assert sorted(load_manifest(out)["key"].to_pylist()) == sorted(keys)
    assert not list((out / "shards").glob("*.partial"))
    convert(ToyAdapter(), src, tmp_path / "whole", workers=1, shard_size=8)  # one process, never interrupted
    assert digests(out) == digests(tmp_path / "whole")


class HauntedToy(ToyAdapter):
    """Converts as the toy does while a task of a killed run, still ending (Ray cancels a dead driver's tasks after
    a moment), writes its fragment of a log this run converts too."""

    def __init__(self, out: str) -> None:
        super().__init__()
        self.out = out

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        shards = Path(self.out) / "shards"
        if log.log_id == "log001":
            (shards / "log-000001.dead.partial").write_bytes(b"half a tar member of the killed run")
        yield from super().iter_samples(log)


def test_a_killed_runs_ending_task_neither_disturbs_nor_litters_the_rerun(tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    write_toy_logs(src, n_logs=4, frames=3)
    (out / "shards").mkdir(parents=True)
    (out / "shards" / "log-000002.dead.partial").write_bytes(b"left by the killed run")
    result = convert(HauntedToy(str(out)), src, out, shard_size=4)
    assert result.ok and result.logs_converted == 4
    convert(ToyAdapter(), src, tmp_path / "whole", shard_size=4)
    assert digests(out) == digests(tmp_path / "whole")


class RiggedToy(ToyAdapter):
    """A toy adapter with an option that changes its samples, like ``carla_lead --rig``."""

    def __init__(self, rig: str = "normal") -> None:
        super().__init__()
        self.rig = rig

    def options(self) -> dict[str, Any]:
        return Adapter.options(self)  # the default: the __init__ parameters kept as attributes


class OtherToy(ToyAdapter):
    name = "other_toy"


def test_a_folder_holds_one_adapter_and_one_set_of_options(tmp_path):
    write_toy_logs(tmp_path / "src", n_logs=2, frames=3)
    convert(RiggedToy(rig="normal"), tmp_path / "src", tmp_path / "out")
    identity = json.loads((tmp_path / "out" / "convert.json").read_text())
    assert identity == {"adapter": "toy", "adapter_version": "1", "options": {"rig": "normal"}}
    with pytest.raises(
        UserError, match=r"by toy 1 \(rig='normal'\), but this run asks for toy 1 \(rig='both'\).*--force"
    ):
        convert(RiggedToy(rig="both"), tmp_path / "src", tmp_path / "out")
    with pytest.raises(UserError, match=r"by toy 1, but this run asks for other_toy 1: pass --force.*new --out"):
        convert(OtherToy(), tmp_path / "src", tmp_path / "out")
    assert len(load_manifest(tmp_path / "out")) == 6  # nothing was touched
    assert convert(RiggedToy(rig="normal"), tmp_path / "src", tmp_path / "out").logs_resumed == 2
    forced = convert(RiggedToy(rig="both"), tmp_path / "src", tmp_path / "out", force=True)
    assert forced.logs_converted == 2 and load_info(tmp_path / "out")["adapter_options"] == {"rig": "both"}


def _descendants(pid: int) -> list[int]:
    """Children, grandchildren...: pool workers are children of a forkserver, the driver's child."""
    path = Path(f"/proc/{pid}/task/{pid}/children")
    children = [int(child) for child in path.read_text().split()] if path.exists() else []
    return children + [grandchild for child in children for grandchild in _descendants(child)]


def _alive(pid: int) -> bool:
    """Running or sleeping; a zombie nobody reaps (pid 1 of a container may not) counts as gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in status


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads the process tree from /proc")
def test_killed_driver_leaves_no_orphaned_workers(tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    write_toy_logs(src, n_logs=6, frames=200)  # ~40 s of work per log at 0.2 s per frame
    code = KILLABLE.replace("sleep=0.02", "sleep=0.2").format(
        tests=str(Path(__file__).parent), src=str(src), out=str(out), workers=2
    )
    driver = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    deadline = time.time() + 60
    while time.time() < deadline and not list((out / "shards").glob("*.partial")):  # workers are converting
        time.sleep(0.05)
    workers = _descendants(driver.pid)
    assert len(workers) >= 2, "the driver should have started its workers"
    os.kill(driver.pid, signal.SIGKILL)  # the driver alone, as an OOM killer would
    driver.wait()
    deadline = time.time() + 10
    while time.time() < deadline and any(_alive(pid) for pid in workers):
        time.sleep(0.1)
    survivors = [pid for pid in workers if _alive(pid)]
    for pid in survivors:  # do not leave them running after a failure
        os.kill(pid, signal.SIGKILL)
    assert not survivors


USER_SCRIPT = """
import os
import sys

with open({marker!r}, "a") as file:  # every import of this script, as __main__ or as a worker's __mp_main__
    file.write(__name__ + "\\n")
sys.path.insert(0, {tests!r})
from toy_adapter import ToyAdapter
from lead_s2r.convert import convert

if __name__ == "__main__":
    assert convert(ToyAdapter(sleep=0.02), {src!r}, {out!r}, workers=2, shard_size=8).ok
"""


def test_workers_do_not_import_the_callers_script_again(tmp_path):
    """A user's script (which may import torch) is imported once for all workers, by their forkserver: spawned
    workers imported it once each before their first log."""
    write_toy_logs(tmp_path / "src", n_logs=8, frames=5)
    marker, script = tmp_path / "imports.txt", tmp_path / "user_script.py"
    tests = str(Path(__file__).parent)
    script.write_text(
        USER_SCRIPT.format(marker=str(marker), tests=tests, src=str(tmp_path / "src"), out=str(tmp_path / "out"))
    )
    subprocess.run([sys.executable, str(script)], check=True, timeout=120)
    assert marker.read_text().split() == ["__main__", "__mp_main__"]
    assert len(keys_in_shards(tmp_path / "out")) == 40
