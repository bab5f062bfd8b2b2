"""A real Ray cluster of two nodes on this machine for the tests: a head and a second raylet, one CPU and 100 MB of
object store each, whose workers can import the test helpers (``toy_adapter``)."""

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ray.cluster_utils import Cluster

NODE = {"num_cpus": 1, "object_store_memory": 100 * 2**20}


@contextmanager
def two_node_cluster() -> Iterator[Cluster]:
    """The cluster, shut down (and ``PYTHONPATH`` restored) on exit; connect with ``cluster.address``."""
    saved = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).parent), saved]))
    cluster = Cluster(initialize_head=True, head_node_args={**NODE, "include_dashboard": False})
    try:
        cluster.add_node(**NODE)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        cluster.shutdown()
        if saved is None:
            del os.environ["PYTHONPATH"]
        else:
            os.environ["PYTHONPATH"] = saved
