"""CPU time of one sample's camera input for LTFv6 on NAVSIM's four 1920x1080 cameras (JPEG decode and layout).

.venv/bin/python benchmarks/camera_input.py --repeats 10

The strip (4 x 1920 wide, 1080 rows at NAVSIM's vertical field of view) shrinks 4x into 1920x270, so the JPEGs are
decoded at 1/4 size. The images are smooth synthetic scenes encoded at q=90, each camera calibrated like NAVSIM's.
"""

import argparse

import cv2
import numpy as np
from cpu_time import cpu_times_ms

from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import LeadConfig

CAMERAS = ("front", "left", "right", "back")


def scene_jpeg(height: int = 1080, width: int = 1920, seed: int = 0) -> bytes:
    y, x = np.mgrid[0:height, 0:width] / width
    image = np.stack([128 + 100 * np.sin(6 * x + 3 * y), 128 + 100 * np.cos(4 * y - 2 * x), 255 * x], axis=2)
    image += np.random.default_rng(seed).normal(0, 20, image.shape)
    image = cv2.GaussianBlur(image, (0, 0), 2).clip(0, 255).astype(np.uint8)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    jpeg = scene_jpeg()
    K = [[1545.0, 0.0, 960.0], [0.0, 1545.0, 540.0], [0.0, 0.0, 1.0]]
    meta = {"cameras": [{"id": name, "width": 1920, "height": 1080, "K": K} for name in CAMERAS]}
    sample = {"__key__": "bench", "meta": meta, **{f"cam_{name}": jpeg for name in CAMERAS}}
    ltfv6 = LeadConfig(use_navsim_data=True, LTF=True, use_planning_decoder=True)
    transform = SourceTransform("navsim", input_spec(ltfv6), list(CAMERAS))
    camera = transform.camera
    rgb = camera.image(sample, camera.plan(sample))  # the plan is made once per rig: cpu_times_ms warms up too
    per_sample = cpu_times_ms(lambda: camera.image(sample, camera.plan(sample)), args.repeats).mean()
    print(f"LTFv6 camera input {tuple(rgb.shape)} from 4 x 1920x1080 JPEGs: {per_sample:.1f} ms CPU per sample")


if __name__ == "__main__":
    main()
