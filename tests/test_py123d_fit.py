"""``lead-s2r fit`` with the smoke recipe trains on a converted 123D source beside a CARLA one (one of its logs
without box velocities)."""

import csv
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("py123d", reason="py123d is installed with --no-deps in CI (docs/datasets/py123d.md)")

from lead_s2r.convert import convert
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import carla_lead as lead
from lead_s2r.synthetic import py123d as synth
from lead_s2r.training.cli import run_lightning_cli
from lead_s2r_adapters.carla_lead import CarlaLeadAdapter
from lead_s2r_adapters.py123d import Py123dAdapter

SMOKE = Path(__file__).parents[1] / "recipes" / "smoke" / "sim2real.yaml"
pytestmark = pytest.mark.usefixtures("one_thread")


def test_smoke_recipe_fits_a_123d_source_beside_carla(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI warns when the process has other arguments
    lead.write_route(tmp_path / "carla_src", 0, 6, np.random.default_rng(0))
    convert(CarlaLeadAdapter(), tmp_path / "carla_src", tmp_path / "carla")
    # the nuPlan-style log without box velocities: null in py123d, unknown (NaN) in our boxes, trained on as such
    synth.write_log(tmp_path / "py123d_src", "log-a", index=0, frames=8, box_velocities=False)
    synth.write_lead_log(tmp_path / "py123d_src", index=1, frames=8)
    convert(Py123dAdapter(), tmp_path / "py123d_src", tmp_path / "py123d")
    unknown = [np.isnan(s["boxes"][:, 7:9]).all() for s in read_samples(tmp_path / "py123d", fields=("boxes",))]
    assert any(unknown) and not all(unknown)  # the nuPlan-style log's boxes, not LEAD's
    config = yaml.safe_load(SMOKE.read_text())
    config["trainer"].update(max_epochs=1, default_root_dir=str(tmp_path / "run"), enable_model_summary=False)
    config["trainer"]["callbacks"] = [c for c in config["trainer"]["callbacks"] if "Scoring" not in c["class_path"]]
    # LEAD's network knows the sources carla, navsim and wod: the 123D source trains as the NAVSIM target (its grid)
    config["model"]["supervise"] = {"carla": ["perception"], "navsim": ["planning"]}  # sim-to-real: real plans
    py123d = {"paths": [str(tmp_path / "py123d")], "cameras": ["front"]}
    config["data"].update(
        train={"carla": {"paths": [str(tmp_path / "carla")], "cameras": ["carla_mosaic"]}, "navsim": py123d},
        val={"navsim": py123d},
        predict={"navsim": py123d},
        schedule={"anchors": {0: {"carla": 2, "navsim": 2}}, "global_batch_size": 4},
        steps_per_epoch=2,
    )
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(config))
    run_lightning_cli(["fit", "--config", str(recipe)])
    with (tmp_path / "run" / "lightning_logs" / "version_0" / "metrics.csv").open() as file:
        rows = list(csv.DictReader(file))
    losses = [float(r["train/navsim/waypoints"]) for r in rows if r.get("train/navsim/waypoints")]
    totals = [float(r["train/loss"]) for r in rows if r.get("train/loss")]
    assert losses and totals and all(np.isfinite(losses + totals))
    assert any(r.get("val/navsim/ade") for r in rows)
