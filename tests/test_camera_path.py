"""The camera path is straight and the transform's outputs did not move (issues 41 and 42).

On every camera case (tests/transform_cases.py: CARLA TFv6 at LeadConfig's defaults, one camera of the mosaic, small
tiles decoded at reduced size, NAVSIM LTFv6, WOD-E2E LTFv6; inputs_on_device off and on) each sample's rig is planned
once and each camera image decoded once, counted where it happens; and every output equals, bit for bit, the digest
the code before these changes made (tests/data/transform_digests.json).
"""

import json
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import pytest
from transform_cases import CASES, DIGESTS, case_samples, case_transform, convert_sources, output_digests

import lead_s2r.data.camera_input as camera_input
import lead_s2r.data.device_inputs as device_inputs
from lead_s2r.data.collate import collate
from lead_s2r.data.device_inputs import RGB_JPEG, decode_images

pytestmark = [pytest.mark.usefixtures("one_thread"), pytest.mark.filterwarnings("ignore:source .*letterboxed")]


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return convert_sources(tmp_path_factory.mktemp("camera_cases"))


@pytest.mark.parametrize("case", CASES)
def test_every_output_is_bit_identical_to_the_code_before(data: dict[str, Path], case: str) -> None:
    expected = json.loads(DIGESTS.read_text())[case]
    assert output_digests(case_transform(case), case_samples(data, case)) == expected


def counting(counts: Counter, name: str, function: Callable, images: Callable[[Any], int]) -> Callable:
    def counted(*args: Any, **kwargs: Any) -> Any:
        counts[name] += images(args[0])
        return function(*args, **kwargs)

    return counted


@pytest.mark.parametrize("case", CASES)
def test_each_sample_plans_its_rig_once_and_decodes_each_camera_once(
    data: dict[str, Path], case: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    counts: Counter = Counter()
    monkeypatch.setattr(camera_input, "camera_plan", counting(counts, "plans", camera_input.camera_plan, lambda _: 1))
    decode_rgb = counting(counts, "decodes", device_inputs.decode_rgb, len)
    monkeypatch.setattr(camera_input, "decode_rgb", decode_rgb)
    monkeypatch.setattr(device_inputs, "decode_rgb", decode_rgb)
    monkeypatch.setattr(cv2, "imdecode", counting(counts, "decodes", cv2.imdecode, lambda _: 1))
    transform = case_transform(case)
    cameras = len(transform.cameras)
    for sample in case_samples(data, case):
        counts.clear()
        out = transform(sample)
        assert counts["plans"] == 1
        sent_encoded = RGB_JPEG in out
        assert sent_encoded == (CASES[case][3] and cameras == 1)  # a mosaic as stored goes to the device encoded
        batch = decode_images(collate([out]), "cpu")  # what the data module's hook does on the training device
        assert tuple(batch["rgb"].shape[-2:]) == transform.spec.image_size
        assert counts == {"plans": 1, "decodes": cameras}, counts


def test_the_cases_take_every_decode_path(data: dict[str, Path]) -> None:
    paths = {case: case_transform(case).camera.plan(case_samples(data, case, 1)[0]).path for case in CASES}
    assert set(paths.values()) == {camera_input.AS_STORED, camera_input.REDUCED, camera_input.FULL}
    assert paths["carla_tfv6"] == camera_input.AS_STORED and paths["carla_small_tiles"] == camera_input.REDUCED
