"""The camera cases of the training transform on generated data, and a digest of everything it outputs.

Each case is a source's converted shards (a generated CARLA route, NAVSIM logs, WOD-E2E segments) and the
:class:`~lead_s2r.data.transforms.SourceTransform` a recipe builds for it. ``tests/data/transform_digests.json`` holds
the digests of the transform's outputs made by the code before the camera path was straightened and the loader sped
up (issue 41, 42): every output must stay bit-identical (dtype, shape, bytes).
"""

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from lead_s2r.convert import convert
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.registry import get_adapter
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import carla_lead, navsim, wod_e2e
from lead_s2r_adapters.navsim import NavsimAdapter
from lead_s2r_adapters.wod_e2e import WodE2EAdapter

DIGESTS = Path(__file__).parent / "data" / "transform_digests.json"

TFV6 = {"use_planning_decoder": True}
NAVSIM_LTFV6 = {"use_navsim_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}
WOD_LTFV6 = {"use_waymo_e2e_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}

#: case -> (source, LEAD config switches, cameras, inputs_on_device). CARLA: LeadConfig's defaults (the 1152x384
#: mosaic as stored), one camera of the mosaic (the camera ablation) and 64x64 tiles (a reduced JPEG decode).
CASES: dict[str, tuple[str, dict[str, Any], list[str], bool]] = {
    "carla_tfv6": ("carla", TFV6, ["carla_mosaic"], False),
    "carla_tfv6_on_device": ("carla", TFV6, ["carla_mosaic"], True),
    "carla_one_camera": ("carla", {**TFV6, "used_cameras": [False, True, False]}, ["carla_mosaic"], False),
    "carla_one_camera_on_device": ("carla", {**TFV6, "used_cameras": [False, True, False]}, ["carla_mosaic"], True),
    "carla_small_tiles": ("carla", {**TFV6, "camera_tile_size": [64, 64]}, ["carla_mosaic"], False),
    "navsim_ltfv6": ("navsim", NAVSIM_LTFV6, ["front_left", "front", "front_right", "back"], False),
    "navsim_ltfv6_on_device": ("navsim", NAVSIM_LTFV6, ["front_left", "front", "front_right", "back"], True),
    "wod_ltfv6": ("wod", WOD_LTFV6, ["front_left", "front", "front_right"], False),
    "wod_ltfv6_on_device": ("wod", WOD_LTFV6, ["front_left", "front", "front_right"], True),
}


def convert_sources(root: Path) -> dict[str, Path]:
    """Generated raw data of each source converted to shards under ``root``: source -> shard folder."""
    writers: dict[str, tuple[Callable[[Path], None], Callable[[Path], Any]]] = {
        "carla": (
            lambda raw: carla_lead.generate(raw, count=1, seed=0, frames=4),
            lambda raw: get_adapter("carla_lead"),
        ),
        "navsim": (
            lambda raw: navsim.generate(raw, count=1, seed=0),
            lambda raw: NavsimAdapter(scene_filter=str(raw / "scene_filters" / "navmini.yaml"), maps=str(raw / "maps")),
        ),
        "wod": (lambda raw: wod_e2e.generate(raw, count=1, seed=3), lambda raw: WodE2EAdapter()),
    }
    out = {}
    for source, (write, adapter) in writers.items():
        raw, data = root / source / "raw", root / source / "data"
        write(raw)
        assert convert(adapter(raw), raw, data).ok
        out[source] = data
    return out


def case_transform(case: str) -> SourceTransform:
    source, switches, cameras, on_device = CASES[case]
    return SourceTransform(source, input_spec(LeadConfig(**switches)), cameras, inputs_on_device=on_device)


def case_samples(data: dict[str, Path], case: str, limit: int = 4) -> list[dict[str, Any]]:
    """The first ``limit`` samples of the case's source, with the fields its transform reads."""
    fields = case_transform(case).fields
    samples = []
    for sample in read_samples(data[CASES[case][0]], fields):
        samples.append(sample)
        if len(samples) == limit:
            break
    return samples


def digest(value: Any) -> str:
    """dtype, shape and bytes of a tensor (in its logical order), those of each in a list, or the value's repr."""
    if isinstance(value, list):
        return "[" + ", ".join(digest(item) for item in value) + "]"
    if isinstance(value, torch.Tensor):
        array = value.contiguous().numpy()
        return f"{array.dtype}{list(array.shape)}:{hashlib.sha256(array.tobytes()).hexdigest()[:24]}"
    return repr(value)


def output_digests(transform: SourceTransform, samples: list[dict[str, Any]]) -> list[dict[str, str]]:
    return [{key: digest(value) for key, value in sorted(transform(sample).items())} for sample in samples]
