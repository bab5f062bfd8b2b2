"""Every smoke twin of a paper recipe fits, predicts and scores on CPU over the quickstart's synthetic data.

Slow (a few minutes on two CPU cores): synthetic data in three formats is generated and converted once, then the twins
run in their init_from order. Deselect with ``-m "not slow"``.
"""

import importlib
import sys
import warnings
from pathlib import Path

import pytest

from lead_s2r.convert import convert
from lead_s2r.registry import get_adapter
from lead_s2r.scoring.run import score_predictions
from lead_s2r.training.cli import run_lightning_cli

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_thread")]

SMOKE = Path(__file__).parents[1] / "recipes" / "smoke"
#: twins in init_from order -> (metric, dataset) their predictions are scored with; None: no predict stage.
TWINS = {
    "carla_tfv6_pretrain": None,
    "carla_tfv6": ("ade", "carla_lead"),
    "navsim_ltfv6_lead": ("ade", "navsim"),
    "wod_ltfv6_pretrain": None,
    "wod_ltfv6_lead": ("rfs@wod-e2e-2025", "wod_e2e"),
    "ego_mlp": ("rfs@wod-e2e-2025", "wod_e2e"),
}


@pytest.fixture(scope="module")
def quickstart_data(tmp_path_factory) -> Path:
    """``<root>/data/{carla_lead,navsim,wod_e2e}`` as the quickstart writes them (training and held-out splits),
    smaller."""
    root = tmp_path_factory.mktemp("twins")
    for dataset, size, options in (
        ("carla_lead", {"count": 2}, {}),
        ("navsim", {"splits": {"trainval": 2, "test": 1}}, {"maps": "maps"}),
        ("wod_e2e", {"splits": {"train": 2, "val": 2}}, {}),
    ):
        raw = root / "raw" / dataset
        importlib.import_module(f"lead_s2r.synthetic.{dataset}").generate(raw, seed=0, **size)
        adapter = get_adapter(dataset, **{name: str(raw / value) for name, value in options.items()})
        assert convert(adapter, raw, root / "data" / dataset, workers=1, progress=False).ok
    return root


def test_every_twin_is_tested():
    assert {p.stem for p in SMOKE.glob("*.yaml")} - {"sim2real"} == set(TWINS)


def test_twins_fit_predict_and_score(quickstart_data, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    for name, scoring in TWINS.items():
        recipe = quickstart_data / f"{name}.yaml"
        recipe.write_text((SMOKE / f"{name}.yaml").read_text().replace("quickstart/", f"{quickstart_data}/"))
        run = quickstart_data / "runs" / name
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter")
            run_lightning_cli(["fit", "--config", str(recipe)])
            assert (run / "checkpoints" / "last.ckpt").exists(), name
            if scoring is None:
                continue
            run_lightning_cli(
                ["predict", "--config", str(recipe), "--ckpt_path", str(run / "checkpoints" / "last.ckpt")]
            )
        metric, dataset = scoring
        report = score_predictions(
            metric,
            run / "predictions.parquet",
            [quickstart_data / "data" / dataset],
            run / "scores",
            allow_missing=True,
        )
        value = report["aggregates"]["rfs" if metric.startswith("rfs") else "ade"]
        assert value is not None and value > 0, (name, report["aggregates"])
