from collections import Counter
from types import SimpleNamespace

import pytest
from tiny_models import sensor_spec

from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.errors import UserError
from lead_s2r.models.config import TrajectoryGrid


def make_datamodule(
    path: str, epoch: int = 0, steps_per_epoch: int | None = 3, rank: int = 0, world_size: int = 1
) -> DriveDataModule:
    grids = {"sim": TrajectoryGrid(4, 0.5), "real": TrajectoryGrid(4, 0.5)}
    inputs = sensor_spec(image_size=(32, 96), trajectory_grids=grids, radar=False)
    spec = SourceSpec([path], cameras=["front"])
    dm = DriveDataModule(
        train={"sim": spec, "real": spec},
        val={"real": spec},
        schedule=MixingSchedule.lead_sim2real("sim", "real", global_batch_size=8),
        steps_per_epoch=steps_per_epoch,
        eval_batch_size=5,
        inputs=inputs,
    )
    dm.trainer = SimpleNamespace(current_epoch=epoch, global_rank=rank, world_size=world_size)
    return dm


def test_training_batches_follow_the_schedule_with_equal_step_counts(toy_data):
    loaders = make_datamodule(toy_data, epoch=0).train_dataloader()
    sizes = {name: [len(batch["__key__"]) for batch in loader] for name, loader in loaders.items()}
    assert sizes == {"sim": [5, 5, 5], "real": [3, 3, 3]}
    late = make_datamodule(toy_data, epoch=31).train_dataloader()
    assert list(late) == ["real"] and [len(b["__key__"]) for b in late["real"]] == [8, 8, 8]


def test_ranks_train_on_samples_of_their_own_each_epoch(toy_data):
    for epoch in (0, 1):
        keys = []
        for rank in (0, 1):
            loaders = make_datamodule(toy_data, epoch=epoch, rank=rank, world_size=2).train_dataloader()
            sizes = {name: [len(batch["__key__"]) for batch in loader] for name, loader in loaders.items()}
            assert sizes == ({"sim": [3] * 3, "real": [1] * 3} if epoch == 0 else {"sim": [2] * 3, "real": [2] * 3})
            keys.append({(name, key) for name, loader in loaders.items() for b in loader for key in b["__key__"]})
        assert keys[0] and keys[1] and not keys[0] & keys[1]
    dm = make_datamodule(toy_data, world_size=2)
    dm.train_sources["sim"] = SourceSpec([toy_data], splits=["val"])  # toy data is all "train"
    with pytest.raises(UserError, match=r"data\.train\.sim: 0 training sample\(s\) .* for 2 rank\(s\)"):
        dm.train_dataloader()


def test_validation_sees_every_sample_once(toy_data):
    (loader,) = make_datamodule(toy_data).val_dataloader()
    keys = [key for batch in loader for key in batch["real"]["__key__"]]
    assert len(keys) == 24 and max(Counter(keys).values()) == 1
    batch = next(iter(loader))["real"]
    assert batch["__dataset__"] == ["toy"] * 5
    assert batch["rgb"].shape == (5, 3, 32, 96) and batch["waypoints"].shape == (5, 4, 2)


def test_split_filter_and_schedule_mismatch(toy_data):
    dm = make_datamodule(toy_data)
    dm.val_sources = {"real": SourceSpec([toy_data], splits=["val"], cameras=["front"])}
    (loader,) = dm.val_dataloader()
    assert list(loader) == []  # toy data is all "train"
    with pytest.raises(ValueError, match="mixes"):
        DriveDataModule(train={"sim": SourceSpec([toy_data])}, schedule=MixingSchedule.constant({"sim": 1, "x": 1}))


def test_without_steps_per_epoch_an_epoch_is_one_pass_over_the_training_samples(toy_data):
    one = DriveDataModule(
        train={"sim": SourceSpec([toy_data])}, schedule=MixingSchedule.constant({"sim": 1}, 5), steps_per_epoch=None
    )
    assert one.epoch_steps() == 5  # 24 toy samples at batch 5: 4.8 steps, rounded up
    dm = make_datamodule(toy_data, steps_per_epoch=None)
    assert dm.epoch_steps() == 6  # both sources read the 24 samples: 48 at the global batch of 8
    assert {name: len(list(loader)) for name, loader in dm.train_dataloader().items()} == {"sim": 6, "real": 6}
    empty = DriveDataModule(train={"sim": SourceSpec([toy_data], splits=["val"])}, steps_per_epoch=None)
    with pytest.raises(UserError, match=r"data\.train: no training samples"):
        empty.epoch_steps()


@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_batches_are_pinned_for_a_gpu_only(toy_data, device):
    dm = make_datamodule(toy_data)
    dm.trainer.strategy = SimpleNamespace(root_device=SimpleNamespace(type=device))
    loaders = [*dm.train_dataloader().values(), *dm.val_dataloader()]
    assert loaders and all(loader.pipeline[0].pin_memory == (device == "cuda") for loader in loaders)  # its DataLoader
