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
