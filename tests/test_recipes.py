"""Every recipe must parse against the current signatures, so a renamed argument cannot rot a recipe unnoticed."""

import sys
from pathlib import Path

import pytest
import yaml

from lead_s2r.cli import main
from lead_s2r.data.mixing import MixingSchedule

ROOT = Path(__file__).parents[1] / "recipes"
#: Training recipes; recipes/paper holds table specs for `lead-s2r table`, and recipes/smoke/twin*.yaml are overlays
#: that only parse on top of a full-scale recipe (tests/test_smoke_twins.py runs them), not LightningCLI configs;
#: so are recipes/multinode/*.yaml (tests/test_multinode.py runs one over the sim-to-real smoke recipe).
RECIPES = sorted(
    p
    for p in ROOT.rglob("*.yaml")
    if p.parent.name not in ("paper", "multinode") and p not in set(ROOT.glob("smoke/twin*.yaml"))
)


@pytest.mark.parametrize("recipe", RECIPES, ids=lambda p: str(p.relative_to(p.parents[1])))
def test_recipe_parses(recipe, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI warns when the process has other arguments
    with pytest.raises(SystemExit) as exit_info:
        main(["fit", "--config", str(recipe), "--print_config"])
    assert exit_info.value.code in (0, None)
    resolved = yaml.safe_load(capsys.readouterr().out)
    schedule = MixingSchedule(**resolved["data"]["schedule"])
    assert set(schedule.sources) == set(resolved["data"]["train"])


def test_there_are_recipes():
    assert len(RECIPES) >= 3
