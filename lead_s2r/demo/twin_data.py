"""``lead-s2r twin-data``: small synthetic data under every ``data/<name>`` path the full-scale recipes read, so a
recipe's smoke twin (the recipe plus ``recipes/smoke/twin.yaml`` and a model overlay) runs unchanged.

The folders are converted the way the recipe headers convert the real data, because the recipes select by what
conversion writes: NAVSIM's navtrain / navtest samples carry the *scene filter's* name as their split (``splits:
[navtrain]``), so each is converted from a split folder with a filter of that name; CARLA folders use ``--rig
both``; the lead360 folder holds LEAD's 6-camera rig, which the 360-degree and front-camera rows cut into tiles;
navhard is the two-stage layout. PDM-Lite data has LEAD's on-disk format, so its folder is LEAD data of another
seed. One log or route each keeps a full set of folders to seconds of conversion.
"""

import shutil
from pathlib import Path

from lead_s2r.convert import convert
from lead_s2r.registry import get_adapter
from lead_s2r.synthetic import carla_lead, navsim, navsim_navhard, wod_e2e

#: data/<name> -> (camera rig, seed) of the LEAD routes written for it.
CARLA_FOLDERS = {
    "carla_lead": (carla_lead.DEFAULT_RIG, 0),
    "carla_pdm_lite": (carla_lead.DEFAULT_RIG, 1),
    "carla_lead360": ("CARLA_LEADERBOARD2_6CAMERAS", 2),
}
#: data/navsim_<filter> -> (OpenScene split folder, seed); the filter's name becomes the samples' split.
NAVSIM_FOLDERS = {"navtrain": ("trainval", 0), "navtest": ("test", 1)}
#: WOD-E2E segments per split.
WOD_SPLITS = {"train": 1, "val": 1}
#: LEAD frames per route (4 Hz).
CARLA_FRAMES = 8


def convert_synthetic(dataset: str, raw: Path, out: Path, workers: int, **options: str) -> int:
    result = convert(get_adapter(dataset, **options), raw, out, workers=workers, force=True)
    if not result.ok or result.samples == 0:
        raise RuntimeError(f"{out}: converting synthetic {dataset} data failed: {result.errors}")
    return result.samples


def write_twin_data(root: Path, workers: int = 1) -> list[str]:
    """Write raw synthetic data under ``root/raw`` and the converted folders under ``root/data``; return their names."""
    raw, data = Path(root) / "raw", Path(root) / "data"
    for name, (rig, seed) in CARLA_FOLDERS.items():
        carla_lead.generate(raw / name, count=1, seed=seed, frames=CARLA_FRAMES, rigs=(rig,))
        convert_synthetic("carla_lead", raw / name, data / name, workers, rig="both")
    for name, (split, seed) in NAVSIM_FOLDERS.items():
        folder = raw / f"navsim_{name}"
        navsim.generate(folder, seed=seed, splits={split: 1})
        scene_filter = shutil.copy(folder / "scene_filters" / "navmini.yaml", folder / "scene_filters" / f"{name}.yaml")
        options = {"split": split, "scene_filter": str(scene_filter), "maps": str(folder / "maps")}
        convert_synthetic("navsim", folder, data / f"navsim_{name}", workers, **options)
    folder, split = raw / "navsim_navhard", navsim_navhard.SPLIT
    navsim_navhard.generate(folder, count=1)
    options = {
        "split": split,
        "scene_filter": str(folder / "scene_filters" / f"{split}.yaml"),
        "maps": str(folder / "maps"),
        "two_stage_mapping": str(folder / "train_test_split" / f"{split}.yaml"),
    }
    convert_synthetic("navsim", folder, data / "navsim_navhard", workers, **options)
    wod_e2e.generate(raw / "wod_e2e", seed=0, splits=WOD_SPLITS)
    convert_synthetic("wod_e2e", raw / "wod_e2e", data / "wod_e2e", workers)
    return sorted(path.name for path in data.iterdir())
