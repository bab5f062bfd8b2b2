"""``lead-s2r closed-loop check RUN``: the agent's leaderboard lifecycle on made-up sensor readings, without a server.

A CARLA evaluation costs a server and hours; a checkpoint that cannot drive should fail in seconds instead. The check
builds the agent as leaderboard 2.0 does (construct, ``set_global_plan``, ``setup``, ``sensors``) and runs a few ticks
of synthetic readings shaped by the agent's own sensor list (noise images, a LiDAR ground ring, radar echoes, GNSS, IMU
and speedometer of an ego at rest on a straight route) through preprocessing, the model and the controllers. It proves
the plumbing (rig, shapes, route state, controls in range), not the driving.
"""

import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from lead_s2r.closed_loop.agent import BRAKE, LeadS2RAgent, vehicle_control
from lead_s2r.closed_loop.controllers import Control
from lead_s2r.closed_loop.route import EARTH_RADIUS_EQUA
from lead_s2r.closed_loop.sensors import GNSS_ID, IMU_ID, SPEED_ID

#: RoadOption LANEFOLLOW: every point of the check's straight route.
LANE_FOLLOW = 4
#: The route: points every ``ROUTE_SPACING`` metres straight ahead (+x in CARLA's world), as far as ``ROUTE_LENGTH``.
ROUTE_SPACING, ROUTE_LENGTH = 10.0, 200.0
#: Readings per synthetic LiDAR half sweep and radar, enough to fill the rasters without costing time.
LIDAR_POINTS, RADAR_POINTS = 4000, 30


@dataclass(frozen=True)
class CheckResult:
    """What a check saw: the rig, the sensor ids, and one control per tick (the first is the agent's brake)."""

    checkpoint: str
    rig: str
    sensors: list[str]
    controls: list[Control]

    def lines(self) -> list[str]:
        steer = [c.steer for c in self.controls]
        throttle = [c.throttle for c in self.controls]
        return [
            f"closed-loop check passed: {self.checkpoint}",
            f"  rig {self.rig}, {len(self.sensors)} sensors: {', '.join(self.sensors)}",
            f"  {len(self.controls)} ticks on synthetic sensor data: steer {min(steer):+.2f}..{max(steer):+.2f}, "
            f"throttle {min(throttle):.2f}..{max(throttle):.2f}, all controls in range",
        ]


def world_to_gnss(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """CARLA world metres -> (lat, lon) degrees with the world origin at (0, 0), CARLA's Mercator mapping."""
    lon = np.degrees(np.asarray(x, np.float64) / EARTH_RADIUS_EQUA)
    lat = 360.0 * np.arctan(np.exp(-np.asarray(y, np.float64) / EARTH_RADIUS_EQUA)) / math.pi - 90.0
    return np.stack([lat, lon], axis=-1)


def straight_route() -> tuple[list, list]:
    """(gps route, world route) as the leaderboard passes them: a straight road ahead of an ego at the origin."""
    x = np.arange(ROUTE_SPACING, ROUTE_LENGTH + ROUTE_SPACING, ROUTE_SPACING)
    gnss = world_to_gnss(x, np.zeros_like(x))
    world = [(SimpleNamespace(location=SimpleNamespace(x=float(v), y=0.0, z=0.0)), LANE_FOLLOW) for v in x]
    gps = [({"lat": float(lat), "lon": float(lon), "z": 0.0}, LANE_FOLLOW) for lat, lon in gnss]
    return gps, world


def synthetic_input(specs: list[dict[str, Any]], frame: int, rng: np.random.Generator) -> dict[str, Any]:
    """``input_data`` for every sensor of ``specs``: an ego at rest at the origin, facing +x (compass pi/2)."""
    data: dict[str, Any] = {}
    for spec in specs:
        kind, sensor = spec["type"], spec["id"]
        if kind == "sensor.camera.rgb":
            reading: Any = rng.integers(0, 255, (spec["height"], spec["width"], 4), dtype=np.uint8)
        elif kind == "sensor.lidar.ray_cast":
            angle, radius = rng.uniform(0, 2 * math.pi, LIDAR_POINTS), rng.uniform(3, 40, LIDAR_POINTS)
            ground = np.full(LIDAR_POINTS, -2.5)  # the sensor sits 2.5 m up
            columns = [radius * np.cos(angle), radius * np.sin(angle), ground, np.ones(LIDAR_POINTS)]
            reading = np.column_stack(columns).astype(np.float32)
        elif kind == "sensor.other.radar":  # depth, altitude, azimuth, velocity
            reading = np.column_stack(
                [rng.uniform(5, 60, RADAR_POINTS), np.zeros(RADAR_POINTS), rng.uniform(-0.7, 0.7, RADAR_POINTS),
                 rng.uniform(-5, 5, RADAR_POINTS)]
            ).astype(np.float32)  # fmt: skip
        elif sensor == GNSS_ID:
            reading = np.array([0.0, 0.0, 0.0])
        elif sensor == IMU_ID:
            reading = np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0, math.pi / 2])
        elif sensor == SPEED_ID:
            reading = {"speed": 0.0}
        else:
            raise ValueError(f"the check has no synthetic reading for sensor {sensor!r} of type {kind!r}")
        data[sensor] = (frame, reading)
    return data


def check_run(run: str | Path, ticks: int = 5, seed: int = 0) -> CheckResult:
    """Build the agent on ``run`` (a run folder, checkpoint or agent YAML) and drive ``ticks`` synthetic ticks; raises
    what the agent raises. Controls out of range are an ``AssertionError`` (a bug, not a user error)."""
    agent = LeadS2RAgent("localhost", 2000, False)
    agent.set_global_plan(*straight_route())
    agent.setup(str(run))
    specs = agent.sensors()
    rng = np.random.default_rng(seed)
    controls = [BRAKE]  # the agent's first tick brakes
    agent.preprocess(synthetic_input(specs, 0, rng), 0.0)
    for tick in range(1, ticks):
        batch = agent.preprocess(synthetic_input(specs, tick, rng), tick * 0.05)
        control = agent.control(agent.predict(batch), speed=0.0)
        assert -1.0 <= control.steer <= 1.0 and 0.0 <= control.throttle <= 1.0 and 0.0 <= control.brake <= 1.0
        controls.append(control)
    if importlib.util.find_spec("carla") is not None:
        vehicle_control(controls[-1])  # the type the leaderboard receives
    agent.destroy()
    return CheckResult(str(run), agent.rig.cameras, [spec["id"] for spec in specs], controls)
