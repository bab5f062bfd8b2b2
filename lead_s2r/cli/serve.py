"""``lead-s2r serve``: a run or LEAD checkpoint folder served to another simulator (AlpaSim's egodriver gRPC)."""

import argparse
import os
import signal
from typing import Any

from lead_s2r.errors import UserError

#: AlpaSim's challenge starter kit reads these (default port 6789); the flags override them.
HOST_ENV, PORT_ENV, DEFAULT_PORT = "ALPASIM_DRIVER_HOST", "ALPASIM_DRIVER_PORT", 6789
#: What ``pip install 'lead-s2r[alpasim]'`` brings.
EXTRA_MODULES = ("carla_driver_interface", "grpc")


def environment_port() -> int:
    value = os.environ.get(PORT_ENV, str(DEFAULT_PORT))
    try:
        return int(value)
    except ValueError:
        raise UserError(f"environment variable {PORT_ENV}={value!r}: not a port number") from None


def cmd_serve_alpasim(args: argparse.Namespace) -> int:
    import torch

    try:
        from lead_s2r.closed_loop.alpasim import serve
    except ModuleNotFoundError as err:  # the extra is not installed
        if err.name not in EXTRA_MODULES:
            raise
        raise UserError(f"serve alpasim needs {err.name}: pip install 'lead-s2r[alpasim]'") from None
    from lead_s2r.closed_loop.alpasim_model import load_served_model

    port = environment_port() if args.port is None else args.port
    device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    served = load_served_model(args.path, args.source, args.pattern, device)
    server, bound = serve(served, args.host, port)
    cameras = ", ".join(slot.id for slot in served.slots)
    print(f"serving {served.path} ({served.source}; cameras {cameras}) as AlpaSim's egodriver on {args.host}:{bound}",
          flush=True)  # fmt: skip
    signal.signal(signal.SIGTERM, lambda *_: server.stop(grace=2))  # docker stop: end calls in flight, then exit
    try:
        server.wait_for_termination()
    except KeyboardInterrupt:
        server.stop(grace=2).wait()
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("serve", help="serve a run to another simulator (AlpaSim's egodriver over gRPC)")
    targets = sub.add_subparsers(dest="target", required=True, metavar="SIMULATOR")
    sub = targets.add_parser("alpasim", help="gRPC egodriver.EgodriverService for AlpaSim (docs/closed_loop.md)")
    sub.add_argument("path", metavar="RUN_OR_LEAD_FOLDER", help="run folder, checkpoint, or LEAD checkpoint folder")
    sub.add_argument("--host", default=os.environ.get(HOST_ENV, "0.0.0.0"), help=f"address to listen on ({HOST_ENV})")
    sub.add_argument("--port", type=int, default=None, help=f"port ({PORT_ENV}, default {DEFAULT_PORT}; 0: any free)")
    sub.add_argument("--device", default=None, help="torch device (default: cuda when available)")
    sub.add_argument("--source", default=None, help="the model's source to plan for (default: navsim if it has one)")
    sub.add_argument("--pattern", default="model*.pth", help="a LEAD folder's weight files (several: its ensemble)")
    sub.set_defaults(run=cmd_serve_alpasim)
