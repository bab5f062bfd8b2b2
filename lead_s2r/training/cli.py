"""``lead-s2r fit|validate|test|predict``: LightningCLI over :class:`DrivingModule` and :class:`DriveDataModule`.

Recipes under ``recipes/`` are plain LightningCLI YAML; every value can be overridden on the command line
(``--trainer.max_epochs=31``) and the resolved config is saved next to each run. jsonargparse's own mistakes (a
missing config file, a value of the wrong type, a section such as ``data: 7`` that is no mapping), values no
constructor can use and a config file that is not UTF-8 text become a :class:`UserError`, one line like every other
verb's, that names the ``--config`` files; a damaged ``ckpt_path`` (on the command line or in a config file), or one
of the removed network, is named before Lightning loads it (:mod:`lead_s2r.formats.torch_file`).

A run's outputs share one root, ``trainer.default_root_dir`` (``runs/<family>/<name>/seed<k>`` in the recipes):
checkpoints in ``<root>/checkpoints`` (a ``ModelCheckpoint`` without ``dirpath``; Lightning alone would bury them in
the logger's version folder), logs and the resolved config in ``<root>/lightning_logs/version_N`` (``config.yaml``
from fit, ``predict_config.yaml`` from predict), predictions in ``<root>/predictions.parquet`` (a
``PredictionWriter`` without ``output``). So ``--trainer.default_root_dir`` moves all of them together.
"""

import argparse
import itertools
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml
from lightning.pytorch import Trainer
from lightning.pytorch.cli import LightningCLI
from torch import nn

from lead_s2r.data.datamodule import DriveDataModule
from lead_s2r.errors import UserError
from lead_s2r.formats import torch_file
from lead_s2r.models.input_spec import InputSpec, input_spec
from lead_s2r.training.distributed import close_process_group
from lead_s2r.training.feedback import fit_summary, run_loggers
from lead_s2r.training.module import DrivingModule

#: The mixing schedule changes batch composition per epoch, and webdataset splits data over ranks itself.
TRAINER_DEFAULTS = {"reload_dataloaders_every_n_epochs": 1, "use_distributed_sampler": False}
VERBS = ("fit", "validate", "test", "predict")
#: Parsers raise instead of printing the whole usage and exiting, so the message reaches ``main()``.
PARSER_KWARGS: dict[str, Any] = {"exit_on_error": False, **{verb: {"exit_on_error": False} for verb in VERBS}}


class DrivingCLI(LightningCLI):
    """LightningCLI that links the model and the data module (:meth:`add_arguments_to_parser`), so the data's source
    names are checked against the model before anything is written, roots checkpoints without a ``dirpath`` at
    ``<default_root_dir>/checkpoints``, logs to CSV and (when installed) TensorBoard beside any logger the config adds,
    ends a fit by saying what it wrote, and refuses to predict with random weights unless asked to (``--untrained``):
    predictions of an untrained model look like any others."""

    def add_arguments_to_parser(self, parser: Any) -> None:
        """Declare the wiring (built in this order): what the network reads to the data module, which checks its
        source names against it; the data module to the module, which reads its :class:`TrainingData` side."""
        parser.link_arguments("model.model", "data.inputs", compute_fn=network_inputs, apply_on="instantiate")
        parser.link_arguments("data", "model.data", apply_on="instantiate")
        parser.add_argument(
            "--untrained", action="store_true", help="predict: use the model's initial weights (no --ckpt_path)"
        )

    def parse_arguments(self, parser: Any, args: Any) -> None:
        """Parse, then check the CRCs of the checkpoint given as ``ckpt_path``, on the command line or in a config
        file: Lightning's ``torch.load`` of it, right after parsing, checks none."""
        super().parse_arguments(parser, args)
        subcommand = self.config.get("subcommand")
        ckpt_path = subcommand and self.config[subcommand].get("ckpt_path")
        if ckpt_path and Path(ckpt_path).is_file():
            torch_file.load(Path(ckpt_path), zip_only=True)  # damage, or the removed network, named in one line

    def before_instantiate_classes(self) -> None:
        if self.subcommand != "predict":
            return
        config = self.config["predict"]
        weights = ("ckpt_path", "model.init_from", "model.model.init_args.checkpoint", "untrained")  # 3rd: LEAD folder
        if not any(config.get(name) for name in weights):
            raise UserError(
                "lead-s2r predict: no weights given; pass --ckpt_path CHECKPOINT (or --model.init_from WEIGHTS, or a "
                "LEAD checkpoint folder as --model.model.init_args.checkpoint), or --untrained to predict with the "
                "model's initial weights"
            )

    def instantiate_classes(self) -> None:
        """Build the model, data and trainer the config describes. A value of the right type but no use to a
        constructor (``decoder_heads: 7`` for a token width of 32) fails there: jsonargparse re-raises it as a
        ValueError, a constructor's own type check as a TypeError; either is the config's mistake."""
        try:
            super().instantiate_classes()
        except (TypeError, ValueError) as err:
            raise UserError(f"cannot build what the config describes: {' '.join(str(err).split())}") from err

    def instantiate_trainer(self, **kwargs: Any) -> Trainer:
        trainer_config = self._get(self.config_init, "trainer", default={})
        root = trainer_config.get("default_root_dir") or Path.cwd()
        kwargs.setdefault("logger", run_loggers(trainer_config.get("logger"), root))
        return super().instantiate_trainer(**kwargs)

    def after_fit(self) -> None:
        log_dir = self.trainer.log_dir  # a broadcast under DDP: every rank asks, rank 0 prints
        if self.trainer.is_global_zero:
            print("\n".join(fit_summary(self.trainer, log_dir)), flush=True)

    def after_instantiate_classes(self) -> None:
        super().after_instantiate_classes()
        for callback in self.trainer.checkpoint_callbacks:
            if callback.dirpath is None:
                callback.dirpath = str(Path(self.trainer.default_root_dir) / "checkpoints")


def network_inputs(network: nn.Module) -> InputSpec:
    """What ``network`` reads (``model.model``), for the data module's transforms to build."""
    return input_spec(network.config)


def run_lightning_cli(args: list[str] | None = None) -> None:
    """Run a LightningCLI subcommand with ``args`` (e.g. ``["fit", "--config", "recipes/..."]``; None: sys.argv)."""
    argv = sys.argv[1:] if args is None else args
    verb = next(iter(argv), "fit")
    configs = config_files(argv)
    # the table builder reads a run's seed from the config fit saved, and a predict into the same run folder (with
    # the recipe's default seed) must not contradict it
    config_filename = "config.yaml" if verb == "fit" else f"{verb}_config.yaml"
    try:
        DrivingCLI(
            DrivingModule,
            DriveDataModule,
            args=args,
            trainer_defaults=TRAINER_DEFAULTS,
            save_config_kwargs={"overwrite": True, "config_filename": config_filename},
            parser_kwargs=PARSER_KWARGS,
        )
    except argparse.ArgumentError as err:
        where = f"--config {', '.join(map(str, configs))}; " if configs else ""
        raise UserError(f"{err} ({where}see lead-s2r {verb} --help)") from None
    except UserError as err:
        if not configs:
            raise
        raise UserError(f"{err} (--config {', '.join(map(str, configs))})") from err
    close_process_group()  # on success only: after a failure another rank may still wait in a collective


def config_files(argv: list[str]) -> list[Path]:
    """The existing files given as ``--config VALUE`` or ``--config=VALUE``, each checked to be UTF-8 text whose
    sections are mappings (a value that is no file, such as an inline YAML string, or YAML that does not parse, is
    left to jsonargparse)."""
    values = [value for name, value in itertools.pairwise(argv) if name == "--config"]
    values += [arg.removeprefix("--config=") for arg in argv if arg.startswith("--config=")]
    files = [Path(value) for value in values if os.path.isfile(value)]
    for file in files:
        try:
            text = file.read_bytes().decode()
        except UnicodeDecodeError as err:
            raise UserError(f"--config {file}: not UTF-8 text ({err})") from None
        try:
            config = yaml.safe_load(text)
        except yaml.YAMLError:
            continue
        for key, value in misshapen_sections(config):
            raise UserError(f"--config {file}: {key} is {value!r}, not a mapping of its settings (key: value lines)")
    return files


def misshapen_sections(node: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """The sections (``trainer``, ``model``, ``data``) and nested ``init_args`` whose value is a number, a boolean or
    a list. jsonargparse hands such a value to the class as ``**value`` ("argument after ** must be a mapping") or
    drops it unread (``trainer: 7``); a mapping, a file name (a string) or nothing is what it reads."""
    children = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in children:
        name = f"{prefix}{key}" if isinstance(node, dict) else f"{prefix.removesuffix('.')}[{key}]"
        section = (not prefix and key in ("trainer", "model", "data")) or key in ("init_args", "dict_kwargs")
        if section and not (value is None or isinstance(value, dict | str)):
            yield name, value
        yield from misshapen_sections(value, f"{name}.")
