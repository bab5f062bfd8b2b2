"""A real Ray cluster of two nodes on this machine for the tests: a head and a second raylet, one CPU and 100 MB of
object store each, whose workers can import the test helpers (``toy_adapter``).

The nodes take Ray's default IP, the machine's outward address, not ``node_ip_address="127.0.0.1"``: with that, the
GCS and raylets listen on 127.0.0.1 only, but a driver's ``ray.init(address="127.0.0.1:PORT")`` rewrites a loopback
host to the outward address (``ray._private.services.resolve_ip_for_localhost``, in
``canonicalize_bootstrap_address``) and retries the refused GCS there every 5 s without end: a hang, not an error
(Ray 2.60; ray-project/ray#59110 reports the same for ``ray start --address 127.0.0.1:6379``)."""

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
