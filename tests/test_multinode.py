"""Two nodes x one process on this machine with torchrun (c10d rendezvous, gloo, CPU) over the sim-to-real smoke
recipe plus recipes/multinode/ddp.yaml: equal step counts, the schedule's per-source per-rank batch sizes, disjoint
training samples per epoch, validation split by sample, one checkpoint, and validation scores equal to one process."""

import json
import os
import socket
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import lightning as L
import pytest
import torch
import yaml

from lead_s2r.cli import main
from lead_s2r.convert import convert
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.registry import get_adapter
from lead_s2r.synthetic import carla_lead, navsim, wod_e2e

ROOT = Path(__file__).parents[1]
EPOCHS, STEPS = 2, 2


class RankRecorder(L.Callback):
    """Writes ``rank<r>.json``: per epoch the train steps, the per-source batch sizes and the ``source/key`` of every
    training sample drawn; the validation keys of the last validation and the metrics logged."""

    def __init__(self, out: str) -> None:
        self.out = Path(out)
        self.steps: Counter[int] = Counter()
        self.sizes: dict[int, dict[str, int]] = {}
        self.train_keys: dict[int, list[str]] = {}
        self.val_keys: list[str] = []

    def on_train_batch_start(self, trainer: L.Trainer, pl_module: Any, batch: Any, batch_idx: int) -> None:
        epoch = trainer.current_epoch
        self.steps[epoch] += 1
        self.sizes[epoch] = {name: len(part["__key__"]) for name, part in batch.items() if not name.startswith("__")}
        parts = {name: part for name, part in batch.items() if not name.startswith("__")}
        drawn = [f"{name}/{key}" for name, part in parts.items() for key in part["__key__"]]
        self.train_keys.setdefault(epoch, []).extend(drawn)

    def on_validation_epoch_start(self, trainer: L.Trainer, pl_module: Any) -> None:
        self.val_keys = []

    def on_validation_batch_start(
        self, trainer: L.Trainer, pl_module: Any, batch: Any, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        self.val_keys += [key for name, part in batch.items() if not name.startswith("__") for key in part["__key__"]]

    def on_validation_end(self, trainer: L.Trainer, pl_module: Any) -> None:
        """Written after every validation: the last one of a fit validates its final weights."""
        record = {
            "world_size": trainer.world_size,
            "num_nodes": trainer.num_nodes,
            "steps": [self.steps[epoch] for epoch in sorted(self.steps)],
            "sizes": [self.sizes[epoch] for epoch in sorted(self.sizes)],
            "train_keys": [self.train_keys[epoch] for epoch in sorted(self.train_keys)],
            "val_keys": self.val_keys,
            "metrics": {name: float(value) for name, value in trainer.callback_metrics.items()},
            "process_group": torch.distributed.is_initialized(),
        }
        (self.out / f"rank{trainer.global_rank}.json").write_text(json.dumps(record))


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The smoke recipe's three datasets, small: ``<root>/data/{carla_lead,navsim,wod_e2e}``."""
    root = tmp_path_factory.mktemp("multinode")
    carla_lead.generate(root / "raw" / "carla_lead", count=2, seed=0, frames=8)
    navsim.generate(root / "raw" / "navsim", seed=0, splits={"trainval": 2, "test": 2})
    wod_e2e.generate(root / "raw" / "wod_e2e", seed=0, splits={"train": 3, "val": 3})
    options = {"navsim": {"maps": str(root / "raw" / "navsim" / "maps")}}
    for name in ("carla_lead", "navsim", "wod_e2e"):
        adapter = get_adapter(name, **options.get(name, {}))
        assert convert(adapter, root / "raw" / name, root / "data" / name).ok
    return root


def smoke_config(root: Path, run: Path) -> Path:
    """recipes/smoke/sim2real.yaml on ``root``'s data, run folder ``run``, a few steps, with the rank recorder."""
    config = yaml.safe_load((ROOT / "recipes/smoke/sim2real.yaml").read_text().replace("quickstart/", f"{root}/"))
    config["trainer"]["default_root_dir"] = str(run)
    config["trainer"]["max_epochs"] = EPOCHS
    config["trainer"]["callbacks"].append({"class_path": "test_multinode.RankRecorder", "init_args": {"out": str(run)}})
    config["data"]["steps_per_epoch"] = STEPS
    path = run.with_suffix(".yaml")
    path.write_text(yaml.safe_dump(config))
    return path


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_two_nodes_train_like_the_schedule_says_and_validate_like_one(data, tmp_path, monkeypatch):
    run = tmp_path / "run"
    run.mkdir()
    config = smoke_config(data, run)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).parent), os.environ.get("PYTHONPATH")])),
    }
    env |= {"OMP_NUM_THREADS": "1", "GLOO_SOCKET_IFNAME": "lo"}
    rendezvous = ["--nnodes", "2", "--nproc-per-node", "1", "--rdzv-backend", "c10d"]
    rendezvous += ["--rdzv-endpoint", f"127.0.0.1:{free_port()}", "--rdzv-id", "lead-s2r-test", "--max-restarts", "0"]
    fit = ["-m", "lead_s2r.cli", "fit", "--config", str(config)]
    fit += ["--config", str(ROOT / "recipes/multinode/ddp.yaml"), "--trainer.accelerator", "cpu"]
    nodes = [
        subprocess.Popen(
            [sys.executable, "-m", "torch.distributed.run", *rendezvous, *fit],
            env=env,
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        for _ in range(2)
    ]
    outputs = [node.communicate(timeout=540)[0].decode(errors="replace") for node in nodes]
    for node, output in zip(nodes, outputs, strict=True):
        assert node.returncode == 0, output[-3000:]
    ranks = [json.loads((run / f"rank{rank}.json").read_text()) for rank in (0, 1)]

    assert ranks[0]["world_size"] == 2 and ranks[0]["num_nodes"] == 2
    assert ranks[0]["steps"] == ranks[1]["steps"] == [STEPS] * EPOCHS
    schedule = MixingSchedule(**yaml.safe_load(config.read_text())["data"]["schedule"])
    for rank in ranks:
        for epoch, sizes in enumerate(rank["sizes"]):
            expected = {source: size for source, size in schedule.batch_sizes(epoch, world_size=2).items() if size}
            assert sizes == expected, (epoch, sizes, expected)
    for epoch in range(EPOCHS):  # each rank trains on samples of its own share of the epoch
        drawn = [set(rank["train_keys"][epoch]) for rank in ranks]
        assert drawn[0] and drawn[1] and not drawn[0] & drawn[1], epoch
    assert not set(ranks[0]["val_keys"]) & set(ranks[1]["val_keys"])  # validation split by sample

    checkpoints = sorted(path.name for path in (run / "checkpoints").iterdir())
    assert len(checkpoints) == 2 and "last.ckpt" in checkpoints  # one run's checkpoint (+ last), not one per node

    one = tmp_path / "one"
    one.mkdir()
    validate = ["validate", "--config", str(smoke_config(data, one)), "--ckpt_path", str(run / "checkpoints/last.ckpt")]
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    assert main(validate) == 0
    single = json.loads((one / "rank0.json").read_text())
    assert sorted(single["val_keys"]) == sorted(ranks[0]["val_keys"] + ranks[1]["val_keys"])
    expected = {name: value for name, value in single["metrics"].items() if name.startswith(("val/", "score/"))}
    assert "val/navsim/ade" in expected and any(name.startswith("score/navsim/") for name in expected)
    for rank in ranks:
        logged = {name: value for name, value in rank["metrics"].items() if name.startswith(("val/", "score/"))}
        assert logged.keys() == expected.keys()
        for name, value in expected.items():
            assert logged[name] == pytest.approx(value, rel=1e-5), name


def test_a_ddp_run_destroys_its_gloo_process_group_before_the_interpreter_exits(data, tmp_path, monkeypatch):
    """Lightning destroys only NCCL groups; a gloo group left to the interpreter's exit aborted a rank now and then
    (SIGABRT after a complete fit). One CPU process under the DDP strategy joins a real gloo group of one."""
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    monkeypatch.setenv("MASTER_ADDR", "127.0.0.1")
    monkeypatch.setenv("MASTER_PORT", str(free_port()))
    ddp = ["--trainer.strategy", "ddp", "--trainer.devices", "1", "--trainer.accelerator", "cpu"]
    assert main(["validate", "--config", str(smoke_config(data, tmp_path)), *ddp]) == 0
    assert json.loads((tmp_path / "rank0.json").read_text())["process_group"]  # the run had one
    assert not torch.distributed.is_initialized()
