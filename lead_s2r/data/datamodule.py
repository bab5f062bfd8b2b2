"""Per-source webdataset pipelines mixed by a :class:`MixingSchedule`: the training data of a sim-to-real run.

Training: one infinite, shard-resampled pipeline per source whose scheduled batch size is non-zero, over this rank's
share of the source's samples in this epoch (disjoint from the other ranks' shares), each cut to ``steps_per_epoch``
batches, so every rank and every source yields the same number of steps (DDP never waits on an exhausted rank); without
``steps_per_epoch``, one pass over the training samples at the global batch, counted from the manifests so it is the
same on every rank. Lightning's ``CombinedLoader`` zips them into ``{source: batch}``. Dataloaders are rebuilt each
epoch (``reload_dataloaders_every_n_epochs=1``) to follow the schedule, and seeded from (seed, epoch, rank, worker) so a
run repeats and a resumed run goes on with the same stream. Evaluation: one finite, ordered pipeline per source, split
over ranks and workers by sample (every sample read exactly once), whose batches come as ``{source: batch}`` like the
training ones. :mod:`lead_s2r.data.streams` says why webdataset's own splitting and seeding do not do.
"""

import gc
import math
import os
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import lightning as L
import torch
import webdataset as wds

from lead_s2r.data.collate import collate
from lead_s2r.data.device_inputs import RGB_JPEG, RGB_LAYOUT, check_device_decode, decode_images, rasterize_points
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.data.streams import SampleShare, StreamSeed, TrainShare, manifest_samples, seeded_shuffle
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.data.vocab_scores import VocabScores
from lead_s2r.errors import UserError
from lead_s2r.models.input_spec import InputSpec
from lead_s2r.models.inputs import Batch
from lead_s2r.shards import ManifestCheck, ShardError, TarSamples, decode_sample, shard_paths


@dataclass
class SourceSpec:
    """Where one source's samples come from and how they become model inputs.

    Args:
        paths: converted folders (``lead-s2r convert`` outputs).
        splits: keep samples whose ``meta.split`` is listed (None keeps all).
        cameras: camera fields stitched left to right (without the ``cam_`` prefix).
        vocab_scores: a ``vocab_scores.pkl`` of ``lead-s2r vocab score``: each sample gets its scene's vocabulary
            targets (``vocab_scores``, ``vocab_scores_mask``; :mod:`lead_s2r.data.vocab_scores`).
    """

    paths: list[str]
    splits: list[str] | None = None
    cameras: list[str] = field(default_factory=lambda: ["carla_mosaic"])
    vocab_scores: str | None = None

    def shards(self) -> list[str]:
        return [shard for path in self.paths for shard in shard_paths(path)]


@dataclass
class _Prepare:
    """A raw webdataset sample -> tensors: only the fields the transform reads are read from the tar and decoded."""

    transform: SourceTransform
    vocab_scores: VocabScores | None = None

    def __call__(self, raw: dict[str, Any]) -> dict[str, Any]:
        sample = decode_sample(raw, self.transform.fields)
        out = self.transform(sample)
        return out if self.vocab_scores is None else self.vocab_scores(sample, out)


def _tagged(source: str, batch: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """An evaluation batch as ``{source: batch}``, the shape every step of the module takes."""
    return {source: batch}


class DriveDataModule(L.LightningDataModule):
    """Mixed-source training data and per-source evaluation data for the TFv6 family.

    Args:
        train: source name -> spec of its training data; names are the model's sources ("carla", "navsim", "wod").
        val: source name -> spec of its validation data.
        predict: source name -> spec of the data to predict on.
        schedule: per-epoch source composition of each global batch (default: equal shares of 8 samples).
        steps_per_epoch: optimizer steps per epoch (every source yields exactly this many batches per rank); None:
            one pass over the training samples (every source's, in its splits) at the global batch, rounded up.
        eval_batch_size: batch size of validation and prediction loaders.
        num_workers: dataloader workers per source.
        shuffle_buffer: samples in each source's shuffle buffer.
        inputs: what the transforms build (:class:`~lead_s2r.models.input_spec.InputSpec`, from a model config by
            :func:`~lead_s2r.models.input_spec.input_spec`); ``lead-s2r fit|predict`` links the model's here.
        seed: seed of shard resampling and shuffling (with the epoch, rank, worker and source); by default the
            one ``seed_everything`` set, else 0.
        inputs_on_device: send the camera JPEGs to the training device encoded, with their rig's layout, to be decoded
            (nvJPEG on a GPU) and laid out there instead of in the loader (PNG cameras and layouts that enlarge are
            laid out in the loader; :mod:`~lead_s2r.data.device_inputs`), and the LiDAR points to be rasterised
            there. None (default): when the trainer runs on a GPU.
    """

    def __init__(
        self,
        train: dict[str, SourceSpec] | None = None,
        val: dict[str, SourceSpec] | None = None,
        predict: dict[str, SourceSpec] | None = None,
        schedule: MixingSchedule | None = None,
        steps_per_epoch: int | None = 100,
        eval_batch_size: int = 8,
        num_workers: int = 0,
        shuffle_buffer: int = 256,
        inputs: InputSpec | None = None,
        seed: int | None = None,
        inputs_on_device: bool | None = None,
    ) -> None:
        super().__init__()
        self.train_sources = train or {}
        self.val_sources = val or {}
        self.predict_sources = predict or {}
        self.schedule = schedule or MixingSchedule.constant({name: 1.0 for name in self.train_sources}, 8)
        unknown = set(self.schedule.sources) - set(self.train_sources)
        if self.train_sources and unknown:
            raise ValueError(f"the schedule mixes {sorted(unknown)} but train lists only {sorted(self.train_sources)}")
        self._steps_per_epoch = steps_per_epoch
        self.eval_batch_size = eval_batch_size
        self.num_workers = num_workers
        self.shuffle_buffer = shuffle_buffer
        self._inputs = inputs
        self._seed = seed
        self._inputs_on_device = inputs_on_device
        self._device_decode_checked = False
        stages = {"train": self.train_sources, "val": self.val_sources, "predict": self.predict_sources}
        for stage, sources in stages.items():
            for name, spec in sources.items():
                try:
                    spec.shards()
                except ShardError as err:
                    raise UserError(f"data.{stage}.{name}.paths: {err}") from None
        if inputs is not None:  # every source needs the model's trajectory grid for it
            for stage, sources in stages.items():
                for name in sources:
                    if name not in inputs.trajectory_grids:
                        raise UserError(
                            f"data.{stage}.{name}: the model knows no source {name!r}; name it one of "
                            f"{sorted(inputs.trajectory_grids)} (the model config's trajectory_grids)"
                        )

    @property
    def inputs(self) -> InputSpec:
        """What the transforms build, as given."""
        if self._inputs is None:
            raise ValueError("DriveDataModule needs to know the model's inputs: pass inputs=input_spec(network.config)")
        return self._inputs

    def epoch_steps(self) -> int:
        """Optimizer steps per epoch: as given, else one pass over the training samples (read once, on first use)."""
        if self._steps_per_epoch is None:
            samples = sum(len(self._samples(spec)[0]) for spec in self.train_sources.values())
            if samples == 0:
                raise UserError("data.train: no training samples in the given paths and splits; check data.train")
            self._steps_per_epoch = math.ceil(samples / self.schedule.global_batch_size)
        return self._steps_per_epoch

    def validation_sources(self) -> list[str]:
        return list(self.val_sources)

    def _where(self) -> tuple[int, int, int]:
        if self.trainer is None:
            return 0, 0, 1
        return self.trainer.current_epoch, getattr(self.trainer, "global_rank", 0), self.trainer.world_size

    @property
    def inputs_on_device(self) -> bool:
        """Whether loaders leave the camera JPEG and the LiDAR points for the device: as given, else on a GPU."""
        return self._inputs_on_device if self._inputs_on_device is not None else self._on_gpu

    @property
    def _on_gpu(self) -> bool:
        strategy = getattr(self.trainer, "strategy", None)
        return strategy is not None and strategy.root_device.type == "cuda"

    def on_before_batch_transfer(self, batch: dict[str, Batch], dataloader_idx: int) -> dict[str, Batch]:
        """Build the inputs the loaders left for the device on the trainer's device, before the rest of the batch
        moves: the camera JPEGs (``rgb_jpeg``) decoded, in one nvJPEG call per source on a GPU, and laid out by their
        rigs' layouts (``rgb_layout``); the LiDAR points (``lidar_points``) rasterised. The first image a GPU decodes
        and lays out in this process is held to the CPU's (:func:`check_device_decode`): a broken decoder fails the
        run at once instead of training on garbage."""
        device = self.trainer.strategy.root_device if self.trainer is not None else torch.device("cpu")
        grid = self.inputs.bev
        decoded = {source: rasterize_points(decode_images(b, device), grid, device) for source, b in batch.items()}
        if device.type != "cpu" and not self._device_decode_checked:
            source = next((source for source, source_batch in batch.items() if RGB_JPEG in source_batch), None)
            if source is not None:
                first = batch[source]
                check_device_decode(first[RGB_JPEG][0], first[RGB_LAYOUT][0], decoded[source]["rgb"][0])
                self._device_decode_checked = True
        return decoded

    def _decode(self, name: str, spec: SourceSpec) -> _Prepare:
        vocab_scores = VocabScores(spec.vocab_scores) if spec.vocab_scores else None
        return _Prepare(SourceTransform(name, self.inputs, list(spec.cameras), self.inputs_on_device), vocab_scores)

    def _train_pipeline(self, name: str, share: TrainShare, batch_size: int) -> wds.DataPipeline:
        prepare = self._decode(name, self.train_sources[name])
        return wds.DataPipeline(
            share.shards,
            TarSamples(prepare.transform.fields),
            share,
            partial(seeded_shuffle, self.shuffle_buffer, share.seed),
            wds.map(prepare),
            wds.batched(batch_size, collation_fn=collate, partial=False),
        )

    @staticmethod
    def _samples(spec: SourceSpec) -> tuple[list[tuple[str, str]], dict[str, list[str]]]:
        """(shard, key) of every sample of the source in its splits, and every key its manifests list per shard."""
        samples: list[tuple[str, str]] = []
        listed: dict[str, list[str]] = {}
        for path in spec.paths:
            selected, keys = manifest_samples(path, spec.splits)
            samples += selected
            listed |= keys
        return samples, listed

    def _eval_pipeline(
        self, name: str, spec: SourceSpec, samples: list[tuple[str, str]], listed: dict[str, list[str]]
    ) -> wds.DataPipeline:
        _, rank, world_size = self._where()
        mine = SampleShare(samples, rank, world_size)
        prepare = self._decode(name, spec)
        return wds.DataPipeline(
            mine.shards,
            TarSamples(prepare.transform.fields),
            ManifestCheck(listed),
            mine,
            wds.map(prepare),
            wds.batched(self.eval_batch_size, collation_fn=collate, partial=True),
            wds.map(partial(_tagged, name)),
        )

    def _loader(self, dataset: wds.DataPipeline) -> wds.WebLoader:
        """A loader over ``dataset``; on a GPU its batches pinned (a pinning thread in the main process), so the copy
        to the device runs asynchronously. No persistent workers: every loader is rebuilt each epoch
        (``reload_dataloaders_every_n_epochs=1``: the schedule, the epoch's seed), which starts new workers anyway."""
        return wds.WebLoader(
            dataset,
            batch_size=None,
            num_workers=self.num_workers,
            pin_memory=self._on_gpu,
            worker_init_fn=_freeze_inherited_objects,
        )

    def current_batch_sizes(self) -> dict[str, int]:
        """Per-rank batch size of each source in the trainer's current epoch."""
        epoch, _, world_size = self._where()
        return self.schedule.batch_sizes(epoch, world_size)

    def train_dataloader(self) -> dict[str, wds.WebLoader]:
        if not self.train_sources:
            raise UserError("no training sources configured (data.train); name one or more sources and their paths")
        epoch, rank, world_size = self._where()
        seed = self._seed if self._seed is not None else int(os.environ.get("PL_GLOBAL_SEED", 0))  # seed_everything's
        loaders = {}
        for name, size in self.current_batch_sizes().items():
            if size > 0:
                samples, _ = self._samples(self.train_sources[name])
                if len(samples) < world_size:  # a rank without samples would wait for a shard forever
                    raise UserError(
                        f"data.train.{name}: {len(samples)} training sample(s) in its paths and splits for "
                        f"{world_size} rank(s), and every rank needs samples of its own; add data or use fewer devices"
                    )
                share = TrainShare(samples, StreamSeed(seed, epoch, rank, name), world_size)
                loaders[name] = self._loader(self._train_pipeline(name, share, size)).with_epoch(self.epoch_steps())
        return loaders

    def _eval_loaders(self, sources: dict[str, SourceSpec], what: str) -> list[wds.WebLoader]:
        if not sources:
            raise ValueError(f"no {what} sources configured (data.{what})")
        found = {name: self._samples(spec) for name, spec in sources.items()}
        world_size = self._where()[2]
        if world_size > 1 and all(len(samples) < world_size for samples, _ in found.values()):
            # the last rank's share would be empty: its DDP never runs the first forward, which syncs buffers
            counts = {name: len(samples) for name, (samples, _) in found.items()}
            raise ValueError(
                f"data.{what}: {counts} samples cannot give each of {world_size} ranks one; every rank must run a "
                "batch (DDP syncs on the first forward). Use fewer devices or more samples."
            )
        return [self._loader(self._eval_pipeline(name, spec, *found[name])) for name, spec in sources.items()]

    def val_dataloader(self) -> list[wds.WebLoader]:
        """One loader per validation source; none configured means no validation loop."""
        return self._eval_loaders(self.val_sources, "val") if self.val_sources else []

    def predict_dataloader(self) -> list[wds.WebLoader]:
        return self._eval_loaders(self.predict_sources, "predict")


def _freeze_inherited_objects(worker_id: int) -> None:
    """A worker starts with its parent's heap (the trainer, torch, Lightning: about half a million objects), which it
    never frees: frozen, the worker's garbage collections stop walking it again (a full collection over it costs tens
    of milliseconds), and a forked worker leaves its pages shared instead of touching each object's GC header."""
    gc.freeze()
