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
