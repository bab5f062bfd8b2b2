"""Every full-scale recipe's smoke twin fits, predicts and scores on CPU over small synthetic data.

A twin is the recipe itself plus the overlays ``recipes/smoke/twin.yaml`` and ``twin_<model>.yaml`` (toy sizes, CPU),
run in a folder whose ``data/`` holds synthetic data converted under the paths the recipes read (``lead-s2r
twin-data``). So this test also checks the real recipes: their data paths and splits, callbacks, switches and
``init_from`` chains (a post-training recipe loads the checkpoint its pre-training twin wrote where the recipe
says). The predict and score stages run the way the recipe headers do: a ``PredictionWriter`` added on the command
line, then the recipe's metric (CARLA: ADE on the training routes, standing in for the closed loop; NAVSIM: PDMS on
navtest and EPDMS on navhard two-stage; WOD-E2E: RFS on val).

Slow (about two minutes on two busy CPU cores; LEAD's networks run on 64x64 camera tiles, see
``recipes/smoke/twin_lead.yaml``): the data are generated and converted once, then the twins run in their init_from
order. Deselect with ``-m "not slow"``.
"""

import math
import sys
import warnings
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import yaml

from lead_s2r.cli import main
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import load_manifest
from lead_s2r.training.cli import run_lightning_cli

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_thread")]

RECIPES = Path(__file__).parents[1] / "recipes"
FAMILIES = ("carla", "navsim", "wod")
FULL_SCALE = sorted(p for family in FAMILIES for p in (RECIPES / family).glob("*.yaml"))
TWIN = RECIPES / "smoke" / "twin.yaml"
#: model class -> the overlay that shrinks it
MODEL_OVERLAYS = {
    "lead_s2r.models.ego_mlp.EgoStatusMLP": RECIPES / "smoke" / "twin_ego_mlp.yaml",
    "lead_s2r.models.lead_driver.LeadDriver": RECIPES / "smoke" / "twin_lead.yaml",
}
PREDICTION_WRITER = "lead_s2r.training.prediction_writer.PredictionWriter"
#: family -> (metric, aggregate, predict folder or None for the recipe's own data.predict, output subfolder)
SCORING: dict[str, list[tuple[str, str, str | None, str]]] = {
    "carla": [("ade", "ade", None, "train")],
    "navsim": [
        ("pdms@navsim-1.1", "pdms", None, "navtest"),
        ("epdms@navsim-2.2", "epdms", "data/navsim_navhard", "navhard"),
    ],
    "wod": [("rfs@wod-e2e-2025", "rfs", None, "val")],
}


def recipe_config(recipe: Path) -> dict[str, Any]:
    return yaml.safe_load(recipe.read_text())


def init_order(recipes: list[Path]) -> list[Path]:
    """Pre-training recipes first (an ``init_from`` reads their checkpoints), otherwise sorted."""
    return sorted(recipes, key=lambda p: ("init_from" in recipe_config(p)["model"], str(p)))


def twin_args(recipe: Path) -> list[str]:
    overlay = MODEL_OVERLAYS[recipe_config(recipe)["model"]["model"]["class_path"]]
    return ["--config", str(recipe), "--config", str(TWIN), "--config", str(overlay)]


@pytest.fixture(scope="module")
def recipe_data(tmp_path_factory) -> Path:
    """A working folder whose ``data/`` holds every converted folder the full-scale recipes read."""
    root = tmp_path_factory.mktemp("twins")
    assert main(["twin-data", "--out", str(root)]) == 0
    return root


def test_every_full_scale_recipe_has_a_twin():
    """A new recipe is twinned by the overlays or fails here (a model class without an overlay)."""
    assert len(FULL_SCALE) >= 26
    classes = {recipe_config(p)["model"]["model"]["class_path"] for p in FULL_SCALE}
    assert classes <= set(MODEL_OVERLAYS), classes - set(MODEL_OVERLAYS)
    assert {p.parent.name for p in FULL_SCALE} == set(SCORING)


def test_recipe_data_holds_every_folder_the_recipes_read(recipe_data):
    wanted = {
        path.split("/")[1]
        for recipe in FULL_SCALE
        for stage in ("train", "val", "predict")
        for spec in recipe_config(recipe)["data"].get(stage, {}).values()
        for path in spec["paths"]
    }
    wanted |= {folder.split("/")[1] for scorings in SCORING.values() for _, _, folder, _ in scorings if folder}
    assert wanted == {p.name for p in (recipe_data / "data").iterdir()}
    splits = {name: set(load_manifest(recipe_data / "data" / name).column("split").to_pylist()) for name in wanted}
    assert splits["navsim_navtrain"] == {"navtrain"} and splits["wod_e2e"] == {"train", "val"}


def predict_args(recipe: Path, root: Path, folder: str | None, output: Path) -> list[str]:
    """The header's predict command: the recipe's checkpoint, a PredictionWriter added on the command line and, for
    another folder (navhard) or a recipe without data.predict (CARLA: its training data), the predict source."""
    config = recipe_config(recipe)
    checkpoint = root / config["trainer"]["default_root_dir"] / "checkpoints" / "last.ckpt"
    args = ["predict", *twin_args(recipe), "--ckpt_path", str(checkpoint)]
    args += [f"--trainer.callbacks+={PREDICTION_WRITER}", f"--trainer.callbacks.output={output}"]
    data = config["data"]
    if "predict" not in data:
        args.append(f"--data.predict={yaml.safe_dump(data['train'], default_flow_style=True).strip()}")
    elif folder is not None:
        (source,) = data["predict"]
        args.append(f"--data.predict.{source}.paths=[{folder}]")
    return args


def predict_specs(recipe: Path, folder: str | None) -> list[tuple[list[str], list[str] | None]]:
    """(paths, splits) of every source the twin predicts on."""
    data = recipe_config(recipe)["data"]
    specs = data.get("predict", data["train"]).values()
    return [([folder] if folder else spec["paths"], spec.get("splits")) for spec in specs]


def predicted_keys(specs: list[tuple[list[str], list[str] | None]]) -> set[str]:
    """Every sample key of those folders and splits."""
    keys = set()
    for paths, splits in specs:
        for path in paths:
            rows = load_manifest(path).select(["key", "split"]).to_pylist()
            keys |= {row["key"] for row in rows if splits is None or row["split"] in splits}
    return keys


def test_twins_fit_predict_and_score(recipe_data, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    monkeypatch.chdir(recipe_data)  # the recipes' data/ and runs/ paths are relative to the working directory
    for recipe in init_order(FULL_SCALE):
        name = f"{recipe.parent.name}/{recipe.stem}"
        run = recipe_data / recipe_config(recipe)["trainer"]["default_root_dir"]
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter")
            run_lightning_cli(["fit", *twin_args(recipe)])
            assert (run / "checkpoints" / "last.ckpt").is_file(), name
            if recipe.stem.endswith("pretrain"):
                continue
            for metric, aggregate, folder, subfolder in SCORING[recipe.parent.name]:
                predictions = run / subfolder / "predictions.parquet"
                run_lightning_cli(predict_args(recipe, recipe_data, folder, predictions))
                specs = predict_specs(recipe, folder)
                keys = set(pq.read_table(predictions, columns=["key"]).column("key").to_pylist())
                assert keys == predicted_keys(specs), (name, subfolder)
                data = [Path(path) for paths, _ in specs for path in paths]
                report = score_predictions(metric, predictions, data, run / subfolder, allow_missing=True)
                value = report["aggregates"][aggregate]
                assert isinstance(value, float) and math.isfinite(value) and value >= 0, (name, report["aggregates"])
