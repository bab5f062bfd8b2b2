"""The main job, end to end on synthetic data: raw data in all three source formats -> adapters -> shards -> the
real-data experiments of the paper's Table 4 as smoke runs (Ego MLP, LTFv6, LTFv6 + LEAD on NAVSIM and WOD-E2E) ->
predictions on held-out logs -> open-loop scores -> the table in the paper's layout, with the logged human ("Expert")
and every model before and after training. Minutes on a laptop CPU; every stage writes real files, and each training
is a smoke twin of a paper recipe run through the same LightningCLI as ``lead-s2r fit``.

The traps: a model judged on the logs it trained on looks better than it is, so the models train on NAVSIM
``trainval`` / WOD-E2E ``train`` and are scored on NAVSIM ``test`` / WOD-E2E ``val`` logs only, which the generators
draw from the same distribution as the training logs. And a few optimizer steps teach a model nothing, so the
quickstart trains the smoke twins for :data:`STEPS` steps (they run a handful in the test suite) and reports every
model before training too: the two rows show what training changed. One seed can rank two models either way, so
every row is the mean and sample std over :data:`SEEDS`, on held-out splits large enough that one log moves a score
by at most 5 points (20 NAVSIM test logs).

The "without LEAD" rows are the LEAD twins with the synthetic CARLA data taken out (:func:`drop_carla`), so the two rows
differ in nothing else. Lightning talks a lot on the console (model summary, tips, deprecation warnings from its
dependencies); the quickstart sends all of it to ``<out>/lightning.log`` so the console shows the stages and the table
(:mod:`lead_s2r.demo.table4`: its rows, columns and console view).
"""

import importlib
import json
import logging
import multiprocessing
import shutil
import signal
import sys
import time
import warnings
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import yaml
from rich.console import Console

from lead_s2r.demo.table4 import CAMERA_RELIANCE, EVAL_SPLITS, EXPERT, TRAINED, UNTRAINED, build_table4, scorings
from lead_s2r.demo.twin_data import convert_synthetic
from lead_s2r.predictions import write_predictions
from lead_s2r.report.loss_curves import plot_loss_curves
from lead_s2r.report.tables import scores_key
from lead_s2r.report.training_log import TRAINING_LOG
from lead_s2r.scoring.baselines import predict_human
from lead_s2r.scoring.navsim.proposals import ReferenceCache
from lead_s2r.scoring.run import SampleCache, score_predictions
from lead_s2r.shards import read_samples
from lead_s2r.training import camera_reliance
from lead_s2r.training.cli import run_lightning_cli

SMOKE = Path(__file__).resolve().parents[2] / "recipes" / "smoke"
#: dataset -> (synthetic logs per split, adapter options relative to the raw folder). One distribution per dataset;
#: enough logs that a model learns something that carries over to the held-out split. WOD-E2E rates one frame per
#: validation segment, as the real data does, so RFS is a mean over about as many frames as there are val segments.
PLAN: dict[str, tuple[dict[str, int] | None, dict[str, str]]] = {
    "carla_lead": (None, {}),
    "navsim": ({"trainval": 32, "test": 20}, {"maps": "maps", "tag_filters": "scene_filters/pedestrians_ahead.yaml"}),
    "wod_e2e": ({"train": 48, "val": 24}, {}),
}
#: Every trained row is the mean and sample std over these seeds (the paper's three); a seed sets the initial
#: weights and the training data's order.
SEEDS = (0, 1, 2)
#: Validation batches per epoch for the loss curves (the first of the held-out logs; the table scores all of them).
VAL_BATCHES = 4
#: dataset -> the family folder its runs sit in (``runs/<family>/<name>/seed<k>``, as in the recipes and Table 4).
FAMILIES = {"navsim": "navsim", "wod_e2e": "wod"}
#: Training name -> its length in the quickstart: (epochs, optimizer steps per epoch). The Ego MLP's steps cost
#: next to nothing and it needs a few hundred to fit the WOD-E2E futures; the LTFv6 twins cost most of the run.
STEPS: dict[str, tuple[int, int]] = {
    "ego_mlp": (8, 50),
    "navsim_ltfv6": (8, 20),
    "navsim_ltfv6_lead": (8, 20),
    "wod_ltfv6_pretrain": (4, 15),
    "wod_ltfv6": (6, 25),
    "wod_ltfv6_lead": (6, 25),
}
LIGHTNING_LOG = "lightning.log"
LOSS_CURVES = "loss_curves.png"


@dataclass(frozen=True)
class Training:
    """One smoke run: the twin it is made from and whether LEAD's synthetic CARLA data is taken out of it."""

    name: str
    recipe: str
    without_lead: bool = False
    predicts: bool = True
    #: the training whose checkpoint of the same seed this one starts from (its recipe's ``init_from``)
    after: str | None = None


TRAININGS = (
    Training("ego_mlp", "ego_mlp"),
    Training("navsim_ltfv6", "navsim_ltfv6_lead", without_lead=True),
    Training("navsim_ltfv6_lead", "navsim_ltfv6_lead"),
    Training("wod_ltfv6_pretrain", "wod_ltfv6_pretrain", predicts=False),
    Training("wod_ltfv6", "wod_ltfv6_lead", without_lead=True),
    Training("wod_ltfv6_lead", "wod_ltfv6_lead", after="wod_ltfv6_pretrain"),
)


#: the scorers that plan a PDM-Closed reference per sample (``reference_cache`` option)
REFERENCE_SCORERS = ("pdms@navsim-1.1", "epdms@navsim-2.2")


@dataclass
class ScoringCaches:
    """What every scoring of one dataset's held-out samples shares, the expert's and each model's: the PDM-Closed
    references (one depends on the scene only; planning it is the slowest scoring step) and the decoded samples."""

    references: ReferenceCache = field(default_factory=ReferenceCache)
    samples: SampleCache = field(default_factory=SampleCache)


def _stage(console: Console, name: str, started: float) -> None:
    console.print(f"[bold green]{name}[/] ({time.perf_counter() - started:.1f} s)")


def quickstart(out: Path, workers: int = 2, console: Console | None = None) -> dict[str, Any]:
    """Run every stage into ``out``; return ``{run id: {dataset: {scorer: aggregates}}}`` (also in summary.json),
    where a run id is ``<training>/trained``, ``<training>/untrained`` or ``expert``."""
    console = console or Console()
    started = time.perf_counter()
    for dataset in PLAN:
        prepare(dataset, out, workers, console, started)
    caches = {dataset: ScoringCaches() for dataset in PLAN}
    results = {"expert": score_expert(out, caches)}
    _stage(console, f"{EXPERT}: logged futures scored on the held-out logs", started)
    results |= train_every_seed(out, workers, console, started, caches)
    (out / "summary.json").write_text(json.dumps(results, indent=2))
    for shown in build_table4(results, out, SEEDS):
        console.print(shown)
    console.print(
        f"Trained {steps_range()} optimizer steps, seeds {', '.join(map(str, SEEDS))}, on NAVSIM trainval / WOD-E2E "
        f"train logs, scored on the held-out NAVSIM {EVAL_SPLITS['navsim']} / WOD-E2E {EVAL_SPLITS['wod_e2e']} logs; "
        "the paper's numbers are on real data.\n"
        f"Table (markdown, LaTeX, CSV): {out / 'table'}; summary: {out / 'summary.json'}; runs (configs, checkpoints, "
        f"predictions, scores, {LOSS_CURVES}): {out / 'runs'}/<family>/<name>/seed<N> (lead-s2r table --spec table4 "
        f"--runs '{out / 'runs'}/*/*/seed*'); Lightning's console output: {out / LIGHTNING_LOG}"
    )
    console.print(f"Report (open in a browser): {write_report(out)}")
    return results


def write_report(out: Path) -> Path:
    """The web report of every run (headline scores, each run's worst samples) and of LTFv6 against the Ego MLP on
    both datasets, scene by scene, the needs-perception scenes first: the table's question. Returns its index.html."""
    from lead_s2r.report.site import build_site

    return build_site([str(out / "runs" / "*" / "*" / "seed*")], out / "report", compare=("ego_mlp", "ltfv6"))


def steps_range() -> str:
    """The fewest to the most optimizer steps a quickstart training takes, as ``60-400``."""
    totals = sorted(epochs * steps for epochs, steps in STEPS.values())
    return f"{totals[0]}-{totals[-1]}" if totals[0] != totals[-1] else str(totals[0])


def prepare(dataset: str, out: Path, workers: int, console: Console, started: float) -> None:
    """Synthetic raw data of ``dataset`` -> ``out/raw/<dataset>`` -> converted ``out/data/<dataset>``."""
    splits, options = PLAN[dataset]
    raw, data = out / "raw" / dataset, out / "data" / dataset
    generator = importlib.import_module(f"lead_s2r.synthetic.{dataset}")
    generator.generate(raw, seed=0, **({} if splits is None else {"splits": splits}))
    _stage(console, f"{dataset}: synthetic raw data -> {raw}", started)
    paths = {name: str(raw / value) for name, value in options.items()}  # the adapter's options
    samples = convert_synthetic(dataset, raw, data, workers, **paths)
    _stage(console, f"{dataset}: {samples} samples converted -> {data}", started)


def score_expert(out: Path, caches: dict[str, ScoringCaches]) -> dict[str, Any]:
    """The logged human trajectory (NAVSIM's HumanAgent) on every held-out sample, scored like a model."""
    results = {}
    for dataset, split in EVAL_SPLITS.items():
        data, run = out / "data" / dataset, run_folder(out, dataset, "expert", 0)
        held_out = (s for s in read_samples(data, fields=["future"]) if s["meta"]["split"] == split)
        path = write_predictions(run / "predictions.parquet", [predict_human(s) for s in held_out])
        results[dataset] = score(path, data, dataset, run / "scores", caches[dataset])
    return results


def run_folder(out: Path, dataset: str, name: str, seed: int) -> Path:
    """``<out>/runs/<family>/<name>/seed0``: the layout of the recipes, which ``lead-s2r table`` reads."""
    return out / "runs" / FAMILIES[dataset] / name / f"seed{seed}"


def scored_on(training: Training) -> tuple[str, ...]:
    """The datasets a training is scored on: the one its name starts with (``navsim_ltfv6``), else every one."""
    prefixed = tuple(d for d, family in FAMILIES.items() if training.name.startswith(f"{family}_"))
    return prefixed or tuple(EVAL_SPLITS)


def home(training: Training) -> tuple[str, str]:
    """(dataset, name) of the folder a training fits in: ``navsim_ltfv6`` -> (``navsim``, ``ltfv6``); a training
    on both datasets (``ego_mlp``) fits in the first one's family and is scored in each."""
    dataset = scored_on(training)[0]
    return dataset, training.name.removeprefix(f"{FAMILIES[dataset]}_")


def stage_folder(out: Path, training: Training, dataset: str, stage: str, seed: int) -> Path:
    """Where a training's predictions and scores on ``dataset`` go: its run folder once trained, ``<name>_untrained``
    for its initial weights (a run of its own, so a table row never mixes the two)."""
    name = home(training)[1]
    return run_folder(out, dataset, name if stage == TRAINED else f"{name}_{UNTRAINED}", seed)


def score(predictions: Path, data: Path, dataset: str, out: Path, caches: ScoringCaches) -> dict[str, Any]:
    """Every scoring the table needs on ``dataset`` (converted in ``data``): ``{scores_key: aggregates}``; files
    under ``out/<scorer>[-<tag>]``. ``caches``: what the scorings of ``data`` share."""
    results = {}
    for scorer, tag in scorings(dataset):
        options = {"reference_cache": caches.references} if scorer in REFERENCE_SCORERS else {}
        folder = out / (scorer if tag is None else f"{scorer}-{tag.replace(':', '-')}")
        # allow_missing: only the held-out samples are predicted
        report = score_predictions(
            scorer, predictions, [data], folder, tag=tag, sample_cache=caches.samples, allow_missing=True, **options
        )
        results[scores_key(scorer, tag)] = report["aggregates"]
    return results


def smoke_config(training: Training, out: Path, seed: int = 0) -> Path:
    """The training's smoke twin with its ``quickstart/`` paths moved under ``out``, its run folder named after the
    training and seed (a CARLA pre-training it starts from: the one of the same seed), as long as :data:`STEPS` says,
    validated on the first :data:`VAL_BATCHES` held-out batches (the loss curves) and, for a run without LEAD, no
    CARLA data; written to ``out/<name>-seed<N>.yaml``."""
    recipe = SMOKE / f"{training.recipe}.yaml"
    if not recipe.exists():
        raise FileNotFoundError(f"{recipe} not found: run the quickstart from a source checkout (pip install -e .)")
    config = yaml.safe_load(recipe.read_text().replace("quickstart/", f"{out.as_posix()}/"))
    config["seed_everything"] = seed
    config["trainer"]["default_root_dir"] = str(run_folder(out, *home(training), seed))
    config["trainer"]["max_epochs"], config["data"]["steps_per_epoch"] = STEPS[training.name]
    config["trainer"]["enable_progress_bar"] = False  # the quickstart's console shows its stages, not every step
    init_from = config["model"].get("init_from")
    if init_from:  # the CARLA pre-training of the same seed: runs/<family>/<name>/seed<N>/checkpoints/last.ckpt
        family, name = Path(init_from).relative_to(out / "runs").parts[:2]
        config["model"]["init_from"] = str(out / "runs" / family / name / f"seed{seed}" / "checkpoints" / "last.ckpt")
    if "predict" in config["data"]:
        config["trainer"]["callbacks"].append({"class_path": f"{camera_reliance.__name__}.CameraReliance"})
        config["data"]["val"] = config["data"]["predict"]
        config["trainer"]["limit_val_batches"] = VAL_BATCHES
        config["model"]["log_val_losses"] = True
    if training.without_lead:
        drop_carla(config)
    path = out / f"{training.name}-seed{seed}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def drop_carla(config: dict[str, Any]) -> None:
    """Take LEAD's synthetic data out of a LightningCLI config: the CARLA source, its supervision, its share of the
    batch, a CARLA pre-training to start from and the network's CARLA heads (``use_carla_data``, as the full-scale
    recipes without LEAD data build it)."""
    config["model"]["model"]["init_args"]["config"]["use_carla_data"] = False
    config["data"]["train"].pop("carla", None)
    config["model"].get("supervise", {}).pop("carla", None)
    config["model"].pop("init_from", None)
    for shares in config["data"]["schedule"]["anchors"].values():
        shares.pop("carla", None)


@contextmanager
def lightning_output_to(log: Path) -> Iterator[None]:
    """Send Lightning's log records, warnings and anything printed (its rich model summary) to ``log``."""
    loggers = [logging.getLogger(name) for name in ("lightning.pytorch", "lightning.fabric")]
    handlers = [list(logger.handlers) for logger in loggers]
    with log.open("a") as file, redirect_stdout(file), redirect_stderr(file), warnings.catch_warnings():
        warnings.simplefilter("default")  # shown once per place, into the log file
        for logger in loggers:
            logger.handlers = [logging.StreamHandler(file)]
        try:
            yield
        finally:
            for logger, saved in zip(loggers, handlers, strict=True):
                logger.handlers = saved


def chains() -> list[tuple[Training, ...]]:
    """The trainings in runs that can go side by side: a pre-training and those that start from it, else one each."""
    grouped = [(t, *(d for d in TRAININGS if d.after == t.name)) for t in TRAININGS if t.after is None]
    return sorted(grouped, key=len, reverse=True)  # the longest first, so no process waits on it at the end


def train_every_seed(
    out: Path, workers: int, console: Console, started: float, caches: dict[str, ScoringCaches]
) -> dict[str, Any]:
    """:func:`train_and_score` for every training and seed, each on one torch thread and up to ``workers`` at a time
    in processes of their own (forked where the platform forks safely, spawned elsewhere). The twins' small steps use
    a second thread poorly (a NAVSIM twin's fit took 61 s CPU on two threads, 27 s on one, beside a busy core), and
    one thread a run makes every number the same on any machine however many cores it has. Results are merged in a
    fixed order, whichever run ends first."""
    jobs = [(chain, seed) for seed in SEEDS for chain in chains()]
    if workers < 2:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return _merged((train_chain(chain, seed, out, caches) for chain, seed in jobs), console, started)
        finally:
            torch.set_num_threads(threads)
    context = multiprocessing.get_context("fork" if sys.platform == "linux" else "spawn")
    others = set(multiprocessing.active_children())  # the caller's own, left alone
    with ProcessPoolExecutor(workers, context, initializer=_start_training_process, initargs=(caches,)) as pool:
        try:
            futures = [pool.submit(train_chain, chain, seed, out) for chain, seed in jobs]
            return _merged((future.result() for future in futures), console, started)
        except BaseException:  # a run that failed, or Ctrl-C: the runs in flight are stopped, not waited for
            for process in set(multiprocessing.active_children()) - others:
                process.kill()  # not terminate(): a SIGTERM handler inherited or set by Lightning's fit would hold
            raise
        finally:  # and those not yet started never start
            pool.shutdown(cancel_futures=True)


#: A training process's scoring caches: the quickstart's, as they were when the process started.
_inherited: dict[str, ScoringCaches] = {}


def _start_training_process(caches: dict[str, ScoringCaches]) -> None:
    """One torch thread, and the quickstart's caches: inherited as they are when forked (no copy of their 20 MB),
    unpickled once when spawned. Ctrl-C is the quickstart's to handle: Lightning would catch it in here and go on to
    score a half-trained model."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)
    _inherited.update(caches)


def _merged(done: Iterator[tuple[dict[str, Any], list[str]]], console: Console, started: float) -> dict[str, Any]:
    """The runs' results in one dict, in the order given; each run's lines shown as it comes."""
    results: dict[str, Any] = {}
    for scored, messages in done:
        results |= scored
        for message in messages:
            _stage(console, message, started)
    return results


def train_chain(
    chain: tuple[Training, ...], seed: int, out: Path, caches: dict[str, ScoringCaches] | None = None
) -> tuple[dict[str, Any], list[str]]:
    """:func:`train_and_score` for each training of ``chain`` in order, with ``caches`` (in a training process: the
    quickstart's); returns the results and one line a training."""
    results, messages = {}, []
    for training in chain:
        scored, message = train_and_score(training, seed, out, caches if caches is not None else _inherited)
        results |= scored
        messages.append(message)
    return results, messages


def train_and_score(
    training: Training, seed: int, out: Path, caches: dict[str, ScoringCaches]
) -> tuple[dict[str, Any], str]:
    """Fit the training's config with ``seed``; draw its loss curves; predict and score the held-out logs with the
    weights before and after training. Returns ``{"<name>/seed<N>/<stage>": {dataset: {scorer: aggregates}}}`` and
    the line the console shows."""
    config = smoke_config(training, out, seed)
    run = run_folder(out, *home(training), seed)
    for dataset in scored_on(training):  # a checkpoint or scores left by an earlier quickstart would pass for new
        for stage in (TRAINED, UNTRAINED):
            shutil.rmtree(stage_folder(out, training, dataset, stage, seed), ignore_errors=True)
    results = {}
    key = f"{training.name}/seed{seed}"
    if training.predicts:
        results[f"{key}/{UNTRAINED}"] = predict_and_score(config, training, UNTRAINED, seed, out, caches)
    with lightning_output_to(out / LIGHTNING_LOG):
        run_lightning_cli(["fit", "--config", str(config)])
    curves = plot_loss_curves(run / "lightning_logs" / "version_0" / TRAINING_LOG, run / LOSS_CURVES, key)
    if training.predicts:
        results[f"{key}/{TRAINED}"] = predict_and_score(config, training, TRAINED, seed, out, caches)
    scored = ", scored before and after" if training.predicts else ""
    return results, f"{key}: trained{scored}; loss curves -> {curves}"


def predict_and_score(
    config: Path, training: Training, stage: str, seed: int, out: Path, caches: dict[str, ScoringCaches]
) -> dict[str, Any]:
    """Predict with ``config``'s model (trained: the run's last checkpoint; untrained: its initial weights) on each
    dataset's held-out logs alone, into the stage's folder of that dataset's family, and score the
    ``predictions.parquet`` the writer left there against that dataset."""
    sources = yaml.safe_load(config.read_text())["data"]["predict"]
    checkpoint = run_folder(out, *home(training), seed) / "checkpoints" / "last.ckpt"
    weights = ["--ckpt_path", str(checkpoint)] if stage == TRAINED else ["--untrained"]
    results = {}
    for dataset in scored_on(training):
        data = out / "data" / dataset
        mine = {name: spec for name, spec in sources.items() if spec["paths"] == [str(data)]}
        if not mine:
            continue
        folder = stage_folder(out, training, dataset, stage, seed)
        args = ["predict", "--config", str(config), f"--data.predict={json.dumps(mine)}"]
        with lightning_output_to(out / LIGHTNING_LOG):
            run_lightning_cli([*args, "--trainer.default_root_dir", str(folder), *weights])
        results[dataset] = score(folder / "predictions.parquet", data, dataset, folder / "scores", caches[dataset])
        reliance_file = folder / camera_reliance.FILENAME
        reliance = json.loads(reliance_file.read_text()) if reliance_file.exists() else {}
        if dataset in reliance:
            results[dataset][CAMERA_RELIANCE] = reliance[dataset]
    return results
