"""The quickstart's LTFv6 twin learns the synthetic NAVSIM task in the quickstart's steps.

Untrained, the twin is tens of metres off on held-out logs (its steps are 8 m a unit); a model that ignores its inputs
at best predicts the training trajectories' mean, over 3 m off here (the mean over these very held-out logs is the best
any input-blind constant does, and the test computes it). A model that reads the ego status gets below the threshold.
LEAD's network with LEAD's scales stays near the constant in the quickstart's steps (4.0 m after 80 steps at 2 px/m);
the twin gets there with the toy scales (``status_scale``, ``trajectory_scale``, ``heading_scale``) at 1 px/m and 160
steps (docs/training.md, "On the one family: toy scales").
"""

import sys

import numpy as np
import pytest
import yaml

from lead_s2r.demo import quickstart as qs
from lead_s2r.report.loss_curves import plot_loss_curves, read_curves
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import read_samples
from lead_s2r.training.cli import run_lightning_cli

#: Held-out ADE (m) the fitted twin must beat: below half the best input-blind constant's.
THRESHOLD = 1.5


def _blind_ade(samples: list[dict]) -> float:
    """ADE of the best constant trajectory on ``samples`` (their own mean): what no input can beat only by luck."""
    futures = np.stack([s["future"][:8, 1:3] for s in samples])
    return float(np.linalg.norm(futures - futures.mean(0), axis=-1).mean())


@pytest.mark.slow
def test_ltfv6_twin_learns_held_out_trajectories_in_the_quickstarts_steps(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI reads it beside its args
    monkeypatch.setitem(qs.PLAN, "navsim", ({"trainval": 16, "test": 4}, {"maps": "maps"}))
    qs.prepare("navsim", tmp_path, 1, qs.Console(quiet=True), 0.0)
    training = qs.Training("navsim_ltfv6", "navsim_ltfv6_lead", without_lead=True)
    config = qs.smoke_config(training, tmp_path, seed=0)
    assert yaml.safe_load(config.read_text())["data"]["steps_per_epoch"] == qs.STEPS["navsim_ltfv6"][1]
    run = qs.run_folder(tmp_path, *qs.home(training), 0)
    run_lightning_cli(["fit", "--config", str(config)])
    predicted = tmp_path / "predicted"
    args = ["predict", "--config", str(config), "--trainer.default_root_dir", str(predicted)]
    run_lightning_cli([*args, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    data = tmp_path / "data" / "navsim"
    report = score_predictions("ade", predicted / "predictions.parquet", data, tmp_path / "ade", allow_missing=True)
    held_out = [s for s in read_samples(data, fields=["future"]) if s["meta"]["split"] == "test"]
    blind = _blind_ade(held_out)
    assert report["aggregates"]["ade"] < THRESHOLD, (report["aggregates"], blind)
    assert blind > 2 * THRESHOLD  # the world is one where reading the inputs matters

    metrics = run / "lightning_logs" / "version_0" / "metrics.csv"
    curves = read_curves(metrics)
    train, val = curves["train/navsim/waypoints"], curves["val/navsim/waypoints"]
    assert len(train) == qs.STEPS["navsim_ltfv6"][0] * qs.STEPS["navsim_ltfv6"][1]  # every step
    assert len(val) == qs.STEPS["navsim_ltfv6"][0] and val[-1][1] < val[0][1]  # every epoch, falling
    png = plot_loss_curves(metrics, run / qs.LOSS_CURVES)
    assert png.read_bytes().startswith(b"\x89PNG")
