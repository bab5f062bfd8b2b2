"""Any run of ours or LEAD checkpoint folder served as AlpaSim's driver: the gRPC service ``egodriver.EgodriverService``
(NVlabs/alpasim ``src/grpc/alpasim_grpc/v0/egodriver.proto``). Usage: ``docs/closed_loop.md``, "AlpaSim".

The protos come from one pinned source, PyPI's ``carla-driver-interface`` (extra ``[alpasim]``), which vendors AlpaSim's
unchanged. Per session the server keeps what AlpaSim sends and on ``drive`` turns it into a schema v1 sample of the
model's source, then runs the training transform (:class:`~lead_s2r.data.transforms.SourceTransform`) and the network
exactly as ``lead-s2r predict`` does: one preprocessing path, so it drives the model as the scores measured it.

- Cameras are matched to the model's (:mod:`.alpasim_model`) by where they look, never by name (AlpaSim's rigs name
  cameras differently per dataset): the scene camera whose optical axis (``rig_to_camera`` is the optical frame in the
  rig: x right, y down, z forward) is nearest a model camera's direction, within half its field of view, fills it
  (:mod:`.alpasim_messages`). Intrinsics and pose become the sample's calibration, so the layout crops the rows the
  model was trained on. Images stay the JPEG bytes AlpaSim sent (the training data was JPEG too).
- Egomotion (poses in AlpaSim's ``local`` frame, dynamic states in the rig frame) gives speed, acceleration and the
  past poses in the current rig frame; the route (rig frame at its timestamp) gives the command as AlpaSim's own
  driver derives it (the lateral offset of the first waypoint 5 m ahead) and target points for models that read them.
- The answer is the model's waypoints on its output grid, timestamped ``time_now_us + t``, expressed as AlpaSim's
  own driver and runtime expect: in the ``local`` frame, anchored at the latest ego pose and led by it (the model
  plans in the rig frame: x forward, y left, origin at the rear axle, the ISO frame of our data).

Every mistake of a client is a gRPC status whose one message names the field (INVALID_ARGUMENT, NOT_FOUND,
FAILED_PRECONDITION); it ends that call only, every other session goes on. ``get_version`` sends the revision of the
camera convention it speaks (AlpaSim's) as carla-driver-interface's metadata, so that package's clients agree.
"""

import functools
import logging
import threading
from collections.abc import Callable
from concurrent import futures
from typing import Any, TypeVar

import grpc
import numpy as np
from carla_driver_interface import contract, protocol

from lead_s2r import __version__
from lead_s2r.closed_loop.alpasim_messages import (
    MAX_COORDINATE_M,
    RequestError,
    Session,
    build_sample,
    check_dynamics,
    invalid,
    jpeg_shape,
    local_trajectory,
    match_cameras,
    pose_matrix,
    precondition,
    scene_camera,
)
from lead_s2r.closed_loop.alpasim_model import ServedModel
from lead_s2r.errors import UserError

logger = logging.getLogger(__name__)

#: The camera convention spoken: ``rig_to_camera`` is the optical frame in the rig, as AlpaSim's renderers declare it.
CONTRACT_REVISION = 2
T = TypeVar("T")
#: A service method: (servicer, request, context) -> response.
Method = Callable[[Any, Any, grpc.ServicerContext], T]


def rpc(method: Method[T]) -> Method[T]:
    """A service method as one call: a client's mistake aborts it with its status, anything else with INTERNAL."""

    @functools.wraps(method)
    def call(self: Any, request: Any, context: grpc.ServicerContext) -> T:
        try:
            return method(self, request, context)
        except RequestError as err:
            context.abort(err.code, str(err))
        except Exception as err:  # a bug: this call fails, the server and every other session go on
            logger.exception("egodriver call failed")
            context.abort(grpc.StatusCode.INTERNAL, f"{type(err).__name__}: {err}")
        raise AssertionError("unreachable: context.abort raises")

    return call


class EgodriverServicer(protocol.EgodriverServiceServicer):
    """``egodriver.EgodriverService`` over one served model, for any number of concurrent sessions."""

    def __init__(self, served: ServedModel) -> None:
        self.served = served
        self.sessions: dict[str, Session] = {}
        self.sessions_lock = threading.Lock()
        self.model_lock = threading.Lock()  # one forward at a time: torch's own threads use every core

    def session(self, uuid: str) -> Session:
        with self.sessions_lock:
            session = self.sessions.get(uuid)
        if session is None:
            raise RequestError(
                grpc.StatusCode.NOT_FOUND, f"session_uuid {uuid!r}: no such session (start_session first)"
            )
        return session

    def get_version(self, request: Any, context: grpc.ServicerContext) -> Any:
        context.send_initial_metadata(contract.contract_metadata(CONTRACT_REVISION))
        return protocol.VersionId(
            version_id=f"lead-s2r {__version__}: {self.served.path.name} ({self.served.source})",
            git_hash="",
            grpc_api_version=protocol.ALPASIM_API_VERSION,
        )

    @rpc
    def start_session(self, request: Any, context: grpc.ServicerContext) -> Any:
        if not request.session_uuid:
            raise invalid("session_uuid: empty")
        declared = list(request.rollout_spec.vehicle.available_cameras)
        revision = contract.client_revision(context, CONTRACT_REVISION)
        declared = contract.cameras_to_revision(declared, revision, CONTRACT_REVISION)
        read = [scene_camera(camera, index) for index, camera in enumerate(declared)]
        cameras = [camera for camera in read if camera is not None]
        unread = [camera.logical_id for camera, seen in zip(declared, read, strict=True) if seen is None]
        slot_of = match_cameras(self.served.slots, cameras, unread)
        used = {c.logical_id: c for c in cameras if c.logical_id in slot_of}
        with self.sessions_lock:
            if request.session_uuid in self.sessions:
                raise precondition(f"session_uuid {request.session_uuid!r}: already started")
            self.sessions[request.session_uuid] = Session(used, slot_of)
        return protocol.SessionRequestStatus()

    @rpc
    def close_session(self, request: Any, context: grpc.ServicerContext) -> Any:
        self.session(request.session_uuid)
        with self.sessions_lock:
            self.sessions.pop(request.session_uuid, None)
        return protocol.Empty()

    @rpc
    def submit_image_observation(self, request: Any, context: grpc.ServicerContext) -> Any:
        session, image = self.session(request.session_uuid), request.camera_image
        slot = session.slot_of.get(image.logical_id)
        if slot is None:  # a camera the model does not read (or one the scene never declared)
            return protocol.Empty()
        shape = jpeg_shape(image.image_bytes)
        if shape is None:
            raise invalid(f"camera_image.image_bytes of camera {image.logical_id!r}: not a decodable JPEG "
                          "(set AlpaSim's image_format: jpeg)")  # fmt: skip
        declared = session.cameras[image.logical_id].calibration
        if shape != (declared["height"], declared["width"]):
            raise invalid(f"camera_image.image_bytes of camera {image.logical_id!r}: {shape[1]}x{shape[0]} "
                          f"pixels, but the camera is declared {declared['width']}x{declared['height']} "
                          "(rollout_spec.vehicle.available_cameras)")  # fmt: skip
        with session.lock:
            previous = session.images.get(slot, (-(2**63), b""))[0]
            if image.frame_end_us < previous:
                raise invalid(f"camera_image.frame_end_us of camera {image.logical_id!r}: {image.frame_end_us} "
                              f"is before the previous frame's {previous}")  # fmt: skip
            session.images[slot] = (image.frame_end_us, bytes(image.image_bytes))
        return protocol.Empty()

    @rpc
    def submit_egomotion_observation(self, request: Any, context: grpc.ServicerContext) -> Any:
        session = self.session(request.session_uuid)
        poses, states = list(request.trajectory.poses), list(request.dynamic_states)
        if states and len(states) != len(poses):
            raise invalid(f"dynamic_states: {len(states)} states for {len(poses)} poses (one per pose)")
        entries = [(p.timestamp_us, pose_matrix(p.pose, f"trajectory.poses[{i}].pose")) for i, p in enumerate(poses)]
        for index, state in enumerate(states):
            check_dynamics(state, f"dynamic_states[{index}]")
        with session.lock:
            known = {timestamp for timestamp, _ in session.poses}  # a runtime may send its history again
            last, new = (session.poses[-1][0] if session.poses else -(2**63)), []
            for index, (timestamp, pose) in enumerate(entries):
                if timestamp in known:
                    continue
                if timestamp <= last:
                    raise invalid(f"trajectory.poses[{index}].timestamp_us: {timestamp} is not after the "
                                  f"previous pose's {last}")  # fmt: skip
                last = timestamp
                new.append((timestamp, pose))
            session.poses.extend(new)
            if states:
                session.dynamics = states[-1]
        return protocol.Empty()

    @rpc
    def submit_route(self, request: Any, context: grpc.ServicerContext) -> Any:
        session = self.session(request.session_uuid)
        points = np.array([[w.x, w.y] for w in request.route.waypoints], np.float64).reshape(-1, 2)
        if not (np.abs(points) < MAX_COORDINATE_M).all():  # False for NaN
            raise invalid(f"route.waypoints: not finite or {MAX_COORDINATE_M:g} m or more away")
        with session.lock:
            session.route = (request.route.timestamp_us, points)
        return protocol.Empty()

    @rpc
    def submit_recording_ground_truth(self, request: Any, context: grpc.ServicerContext) -> Any:
        """Accepted and unused: the model plans from its sensors, never from the recording."""
        self.session(request.session_uuid)
        return protocol.Empty()

    @rpc
    def drive(self, request: Any, context: grpc.ServicerContext) -> Any:
        session = self.session(request.session_uuid)
        with session.lock:
            sample, anchor = self.prepare(session, request.time_now_us)
        with self.model_lock:
            plan = self.served.plan(sample)
        if not np.isfinite(plan).all():  # never a pose that is not a number to the simulator
            raise RuntimeError("the model's plan is not finite")
        return protocol.DriveResponse(trajectory=local_trajectory(plan, self.served.grid_times, anchor,
                                                                  request.time_now_us))  # fmt: skip

    def prepare(self, session: Session, time_now_us: int) -> tuple[dict[str, Any], tuple[int, np.ndarray]]:
        """The sample of this step and the anchor pose (timestamp, 4x4 local), after the step's checks."""
        if time_now_us <= session.last_drive_us:
            raise invalid(f"time_now_us: {time_now_us} is not after the previous drive's {session.last_drive_us}")
        if not session.poses:
            raise precondition("drive: no egomotion observation yet (submit_egomotion_observation first)")
        if time_now_us < session.poses[-1][0]:
            raise invalid(f"time_now_us: {time_now_us} is before the latest egomotion pose's {session.poses[-1][0]}")
        missing = sorted(set(session.slot_of.values()) - set(session.images))
        if missing:
            names = [logical for logical, slot in session.slot_of.items() if slot in missing]
            raise precondition(f"drive: no image yet from cameras {names} (submit_image_observation first)")
        sample = build_sample(session, self.served, time_now_us)
        session.last_drive_us, session.drives = time_now_us, session.drives + 1
        return sample, session.poses[-1]


def serve(served: ServedModel, host: str, port: int, workers: int = 32) -> tuple[grpc.Server, int]:
    """Start the service on ``host:port`` (0: a free port); the server and the port it listens on."""
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=workers), options=protocol.channel_options())
    protocol.add_EgodriverServiceServicer_to_server(EgodriverServicer(served), server)
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        bound = server.add_insecure_port(address)
    except RuntimeError as err:
        raise UserError(f"--host/--port {address}: cannot listen there ({err})") from None
    if bound == 0:
        raise UserError(f"--host/--port {address}: cannot listen there (in use, or not an address of this machine)")
    server.start()
    return server, bound
