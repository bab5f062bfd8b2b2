import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))  # toy_adapter, importable by spawned workers too


@pytest.fixture
def one_thread():
    """Model tests on one intra-op thread: on a small shared CPU more threads oversubscribe and crawl."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def toy_data(tmp_path_factory) -> str:
    """A converted toy dataset: 4 logs x 6 frames with a camera, LiDAR, boxes and target points."""
    from toy_adapter import ToyAdapter, write_toy_logs

    from lead_s2r.convert import convert

    root = tmp_path_factory.mktemp("toy")
    write_toy_logs(root / "src", n_logs=4, frames=6)
    convert(ToyAdapter(), root / "src", root / "data", shard_size=6)
    return str(root / "data")


@pytest.fixture(scope="session")
def carla_samples(tmp_path_factory) -> list[dict]:
    """Three frames of a generated LEAD route, as the adapter yields them (every field, decoded)."""
    from lead_s2r.registry import get_adapter
    from lead_s2r.synthetic.carla_lead import generate

    src = tmp_path_factory.mktemp("lead")
    generate(src, count=1, seed=7, frames=3)
    adapter = get_adapter("carla_lead")
    return [sample for log in adapter.list_logs(src) for sample in adapter.iter_samples(log)]
