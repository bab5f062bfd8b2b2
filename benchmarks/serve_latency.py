"""Time per ``drive`` of ``lead-s2r serve alpasim`` on CPU, and the share spent outside the network.

.venv/bin/python benchmarks/serve_latency.py --steps 30 --threads 2

The server runs in this process on loopback; a client plays one AlpaSim step after another at AlpaSim's four 480x270
JPEG cameras (front, front left, front right, back): egomotion, route, images, ``drive``. Two models, LEAD's LTFv6 on
NAVSIM (recipes/navsim/ltfv6_lead.yaml's network) at full size and its smoke twin (recipes/smoke/twin_lead.yaml over
it), with random weights (time does not depend on them). Per drive: the client's wall time, the network's forward, the
JPEG decode and layout (``CameraInput.image``); outside the network = drive - forward, and that without the decode.
"""

import argparse
import io
import statistics
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import grpc
import numpy as np
import torch
import yaml
from carla_driver_interface import protocol
from carla_driver_interface.geometry import Pose, waypoints_to_proto
from carla_driver_interface.testing import FakeCamera, render_road
from PIL import Image

from lead_s2r.closed_loop.alpasim import serve
from lead_s2r.closed_loop.alpasim_model import ServedModel, camera_slots
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver

ROOT = Path(__file__).parent.parent
CAMERAS = tuple(FakeCamera(f"camera_{yaw}", 480, 270, 63.7, yaw_left_deg=yaw) for yaw in (55, 0, -55, 180))


def lead_config(*recipes: str) -> LeadConfig:
    """The LEAD config of a recipe with overlays (their ``model.model.init_args.config``, merged key by key)."""
    fields: dict[str, Any] = {}
    for recipe in recipes:
        fields |= yaml.safe_load((ROOT / recipe).read_text())["model"]["model"]["init_args"]["config"]
    return LeadConfig.from_json(fields)


def timed(function: Callable, seconds: list[float]) -> Callable:
    """``function``, appending the wall seconds of each call to ``seconds`` (the network's forward, the decode)."""

    def call(*args: Any) -> Any:
        start = time.perf_counter()
        out = function(*args)
        seconds.append(time.perf_counter() - start)
        return out

    return call


def jpeg(camera: FakeCamera) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(render_road(camera, Pose.identity())).save(buffer, format="JPEG", quality=90)
    return buffer.getvalue()


def drive_times(target: str, steps: int) -> list[float]:
    """Client wall time of each ``drive`` of one session of ``steps`` AlpaSim steps."""
    stub = protocol.EgodriverServiceStub(grpc.insecure_channel(target))
    session = str(uuid.uuid4())
    request = protocol.DriveSessionRequest(session_uuid=session)
    request.rollout_spec.vehicle.available_cameras.extend(camera.available_camera() for camera in CAMERAS)
    stub.start_session(request)
    images = {camera.logical_id: jpeg(camera) for camera in CAMERAS}
    route = np.column_stack([np.arange(0.0, 100.0, 2.0), np.zeros(50), np.zeros(50)])
    seconds = []
    for step in range(steps):
        now = (step + 1) * 100_000
        egomotion = protocol.RolloutEgoTrajectory(session_uuid=session)
        egomotion.trajectory.poses.append(Pose.from_xyz_yaw(0.5 * step, 0.0, 0.0, 0.0).to_proto_at_time(now))
        egomotion.dynamic_states.add().linear_velocity.x = 5.0
        stub.submit_egomotion_observation(egomotion)
        stub.submit_route(protocol.RouteRequest(session_uuid=session, route=protocol.Route(
            timestamp_us=now, waypoints=waypoints_to_proto(route))))  # fmt: skip
        for logical_id, data in images.items():
            image = protocol.RolloutCameraImage(session_uuid=session)
            image.camera_image.logical_id, image.camera_image.frame_end_us = logical_id, now
            image.camera_image.image_bytes = data
            stub.submit_image_observation(image)
        start = time.perf_counter()
        stub.drive(protocol.DriveRequest(session_uuid=session, time_now_us=now, time_query_us=now + 100_000))
        seconds.append(time.perf_counter() - start)
    stub.close_session(protocol.DriveSessionCloseRequest(session_uuid=session))
    return seconds


def stats(values: list[float]) -> str:
    ms = np.asarray(values) * 1e3
    return f"median {statistics.median(ms):7.2f} ms  p99 {np.percentile(ms, 99):7.2f} ms"


def measure(name: str, config: LeadConfig, steps: int) -> None:
    model = LeadDriver(config=config).eval()
    spec = input_spec(config)
    with tempfile.TemporaryDirectory() as folder:  # no run folder: LEAD's cameras of its target
        slots = camera_slots(config, spec, "navsim", Path(folder))
    served = ServedModel(model, "navsim", spec, slots, torch.device("cpu"), Path(name))
    forward, decode = [], []
    served.model = timed(model, forward)
    served.transform.camera.image = timed(served.transform.camera.image, decode)
    server, port = serve(served, "127.0.0.1", 0)
    try:
        drive_times(f"127.0.0.1:{port}", 3)  # warm-up
        forward.clear(), decode.clear()
        drives = drive_times(f"127.0.0.1:{port}", steps)
    finally:
        server.stop(0).wait()
    outside = [d - f for d, f in zip(drives, forward, strict=True)]
    print(f"{name}: image {spec.image_size[1]}x{spec.image_size[0]}, {len(slots)} cameras, {steps} drives")
    print(f"  drive                         {stats(drives)}")
    print(f"  network forward               {stats(forward)}")
    share = statistics.median(outside) / statistics.median(drives)
    print(f"  outside the network           {stats(outside)}  ({share:.0%} of the median drive)")
    print(f"  ... of which JPEG decode      {stats(decode)}")
    print(f"  outside, without JPEG decode  {stats([o - d for o, d in zip(outside, decode, strict=True)])}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    full = "recipes/navsim/ltfv6_lead.yaml"
    measure("smoke twin (LTFv6 + twin_lead)", lead_config(full, "recipes/smoke/twin_lead.yaml"), args.steps)
    measure("LTFv6 full size", lead_config(full), args.steps)


if __name__ == "__main__":
    main()
