"""Two gloo processes on CPU (Lightning's ``ddp_fork``): validation splits by sample, the scoring callback scores
every sample once, every rank logs what one process logs, and both ranks train the same number of steps."""

import faulthandler
import json
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import lightning as L
import pytest
import torch
from lightning.pytorch.strategies import DDPStrategy
from tiny_models import TOY_LTFV6
from toy_adapter import ToyAdapter, write_toy_logs

from lead_s2r.convert import convert
from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_driver import ltfv6_navsim
from lead_s2r.training.cli import TRAINER_DEFAULTS
from lead_s2r.training.module import DrivingModule
from lead_s2r.training.scoring_callback import ScoringCallback

pytestmark = pytest.mark.usefixtures("one_thread")  # forked ranks must not inherit a busy OpenMP pool


@pytest.fixture(scope="module")
def one_shard(tmp_path_factory) -> str:
    """35 samples in a single shard: split by shard, rank 1 would get none."""
    root = tmp_path_factory.mktemp("one_shard")
    write_toy_logs(root / "src", n_logs=5, frames=7)
    convert(ToyAdapter(), root / "src", root / "data", shard_size=1000)
    assert len(list((root / "data" / "shards").glob("*.tar"))) == 1
    return str(root / "data")


class Recorder(L.Callback):
    """Writes ``rank<r>.json`` at the end of the fit: train steps per epoch, validation keys, logged metrics."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.steps: Counter[int] = Counter()
        self.val_keys: list[str] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.steps[trainer.current_epoch] += 1

    def on_validation_epoch_start(self, trainer, pl_module) -> None:
        self.val_keys = []

    def on_validation_batch_start(self, trainer, pl_module, batch, batch_idx, dataloader_idx=0) -> None:
        self.val_keys += [key for name, part in batch.items() if not name.startswith("__") for key in part["__key__"]]

    def on_fit_end(self, trainer, pl_module) -> None:
        record = {
            "steps": [self.steps[epoch] for epoch in sorted(self.steps)],
            "val_keys": self.val_keys,
            "metrics": {name: float(value) for name, value in trainer.callback_metrics.items()},
        }
        (self.out / f"rank{trainer.global_rank}.json").write_text(json.dumps(record))


class CountingScoring(ScoringCallback):
    """Records the keys of every prediction it scores, per rank."""

    def __init__(self, data: str, out: Path) -> None:
        super().__init__(data, metrics=["ade"], prefix="score")
        self.out = out

    def compute(self, predictions):
        with (self.out / "scored.jsonl").open("a") as file:
            file.write(json.dumps([p.key for p in predictions]) + "\n")
        return super().compute(predictions)


def make_parts(
    data: str, out: Path, more_val: dict[str, str] | None = None
) -> tuple[DrivingModule, DriveDataModule, list[L.Callback]]:
    """A tiny LTFv6 with CARLA heads trained on ``data`` as source navsim, validated on it and on ``more_val`` (source
    -> folder)."""
    torch.manual_seed(0)
    val = {"navsim": data} | (more_val or {})
    spec = SourceSpec([data], cameras=["front"])
    network = ltfv6_navsim(**TOY_LTFV6, use_carla_data=True)
    datamodule = DriveDataModule(
        train={"navsim": spec},
        val={source: SourceSpec([folder], cameras=["front"]) for source, folder in val.items()},
        schedule=MixingSchedule.constant({"navsim": 1.0}, 4),
        steps_per_epoch=2,
        eval_batch_size=8,
        shuffle_buffer=8,
        inputs=input_spec(network.config),
    )
    module = DrivingModule(network, lr=1e-3, data=datamodule)  # wired as `lead-s2r fit` links them
    return module, datamodule, [Recorder(out), CountingScoring(data, out)]


def trainer(devices: int, callbacks: list[L.Callback], **options) -> L.Trainer:
    return L.Trainer(
        accelerator="cpu",
        devices=devices,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        callbacks=callbacks,
        **TRAINER_DEFAULTS,
        **options,
    )


def test_two_ranks_validate_like_one(one_shard, tmp_path):
    module, datamodule, callbacks = make_parts(one_shard, tmp_path)
    strategy = DDPStrategy(start_method="fork", find_unused_parameters=True)  # heads without a loss stay unused
    trainer(2, callbacks, strategy=strategy, max_epochs=2).fit(module, datamodule=datamodule)
    ranks = [json.loads((tmp_path / f"rank{rank}.json").read_text()) for rank in (0, 1)]
    assert ranks[0]["steps"] == ranks[1]["steps"] == [2, 2]
    assert [len(rank["val_keys"]) for rank in ranks] == [18, 17]  # split by sample, not by shard
    assert not set(ranks[0]["val_keys"]) & set(ranks[1]["val_keys"])
    scored = [json.loads(line) for line in (tmp_path / "scored.jsonl").read_text().splitlines()]
    assert len(scored) == 2  # once per validation epoch, on rank 0 only
    assert sorted(scored[-1]) == sorted(ranks[0]["val_keys"] + ranks[1]["val_keys"])  # each sample once

    # the fit ends with a validation of its final weights, which come back to this process
    single = trainer(1, [ScoringCallback(one_shard, metrics=["ade"], prefix="score")])
    single.validate(module, datamodule=make_parts(one_shard, tmp_path)[1], verbose=False)
    expected = {name: float(value) for name, value in single.callback_metrics.items()}
    assert {"val/navsim/ade", "val/navsim/fde", "score/toy/ade", "score/toy/fde"} <= set(expected)
    for rank in ranks:
        logged = {name: value for name, value in rank["metrics"].items() if name.startswith(("val/", "score/"))}
        assert logged.keys() == expected.keys()
        for name, value in expected.items():
            assert logged[name] == pytest.approx(value, rel=1e-5), (name, logged, expected)


@pytest.fixture(scope="module")
def one_sample(tmp_path_factory) -> str:
    root = tmp_path_factory.mktemp("one_sample")
    write_toy_logs(root / "src", n_logs=1, frames=1)
    convert(ToyAdapter(), root / "src", root / "data")
    return str(root / "data")


def test_a_rank_without_samples_of_a_source_still_syncs_its_metrics(one_shard, one_sample, tmp_path):
    """Source "carla" has one validation sample: rank 1 sees none of it, yet must compute (and so sync) its metrics,
    which it used to make only on its first batch of that source: rank 0 then waited forever (here: a hang turns
    into a failed run after 5 minutes)."""
    module, datamodule, callbacks = make_parts(one_shard, tmp_path, more_val={"carla": one_sample})
    strategy = DDPStrategy(start_method="fork", find_unused_parameters=True)
    faulthandler.dump_traceback_later(300, exit=True)
    try:
        trainer(2, callbacks, strategy=strategy, max_epochs=1).fit(module, datamodule=datamodule)
    finally:
        faulthandler.cancel_dump_traceback_later()
    ranks = [json.loads((tmp_path / f"rank{rank}.json").read_text()) for rank in (0, 1)]
    assert [len(rank["val_keys"]) for rank in ranks] == [18 + 1, 17]
    assert ranks[0]["metrics"]["val/carla/ade"] == ranks[1]["metrics"]["val/carla/ade"] > 0


def test_too_few_evaluation_samples_for_the_ranks_is_an_error_on_every_rank(one_sample):
    """With fewer samples than ranks the last rank would never run DDP's first forward (a buffer sync) and the
    others would wait for it: every rank refuses at once instead."""
    module, datamodule, _ = make_parts(one_sample, Path("."))
    for rank in (0, 1):
        datamodule.trainer = SimpleNamespace(current_epoch=0, global_rank=rank, world_size=2, lightning_module=module)
        with pytest.raises(ValueError, match=r"data.val: \{'navsim': 1\} samples cannot give each of 2 ranks one"):
            datamodule.val_dataloader()
    datamodule.trainer = SimpleNamespace(current_epoch=0, global_rank=0, world_size=1, lightning_module=module)
    assert len(datamodule.val_dataloader()) == 1
