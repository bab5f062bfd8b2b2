"""How far the device's camera layout is from the loader's, on generated WOD-E2E frames at the real camera sizes.

.venv/bin/python benchmarks/device_layout.py --frames 24

The WOD-E2E LTFv6 recipe's three front cameras (972x1079 each) into 972x360, three ways: the loader's (libjpeg's 1/2
DCT-scaled decode, then OpenCV ``INTER_AREA``: ``camera_input.REDUCED``), a full decode + OpenCV ``INTER_AREA``
(``camera_layout.render``), and ``inputs_on_device``'s (full decode, area-weight products: ``device_inputs``, here
with device='cpu', libjpeg-turbo). Prints the mean and max absolute difference (levels of 255) of each pair over the
frames, and the share of values that differ.
"""

import argparse
import itertools
import tempfile
from pathlib import Path

import cv2
import numpy as np

from lead_s2r.convert import convert
from lead_s2r.data.camera_layout import render
from lead_s2r.data.collate import collate
from lead_s2r.data.device_inputs import decode_images
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.registry import get_adapter
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import wod_e2e

CAMERAS = ["front_left", "front", "front_right"]
LTFV6 = {"use_waymo_e2e_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    args = parser.parse_args()
    config = input_spec(LeadConfig(**LTFV6))
    loader = SourceTransform("wod", config, CAMERAS)
    device = SourceTransform("wod", config, CAMERAS, inputs_on_device=True)
    images: dict[str, list[np.ndarray]] = {"loader (reduced decode)": [], "full decode + INTER_AREA": [], "device": []}
    with tempfile.TemporaryDirectory() as tmp:
        raw, data = Path(tmp) / "raw", Path(tmp) / "data"
        wod_e2e.generate(raw, count=2, seed=0, splits={"train": 2}, image_scale=1.0)
        convert(get_adapter("wod_e2e"), raw, data)
        for _, sample in zip(range(args.frames), read_samples(data, loader.fields), strict=False):
            plan = loader.camera.plan(sample)
            full = [loader.camera.decode(sample, camera, cv2.IMREAD_COLOR_RGB) for camera in CAMERAS]
            images["loader (reduced decode)"].append(loader(sample)["rgb"].permute(1, 2, 0).numpy())
            images["full decode + INTER_AREA"].append(render(plan.layout, full, cv2.INTER_AREA, 0))
            rgb = decode_images(collate([device(sample)]), "cpu")["rgb"][0]
            images["device"].append(rgb.permute(1, 2, 0).numpy())
    print(f"{len(images['device'])} frames, plan {plan.path!r}, {plan.layout.strip} -> {plan.layout.box[2:]}")
    for a, b in itertools.combinations(images, 2):
        difference = np.abs(np.stack(images[a]).astype(int) - np.stack(images[b]).astype(int))
        print(
            f"{a} vs {b}: mean {difference.mean():.2f}, max {difference.max()}, "
            f"{(difference > 0).mean():.0%} of values differ"
        )


if __name__ == "__main__":
    main()
