"""GNSS + compass -> a local pose, and LEAD's route target points and commands at run time.

Traps handled here:
- CARLA converts world locations to GNSS with a map-specific geo reference, and Town13's is not (0, 0) in CARLA
  0.9.15: a fixed reference puts the ego hundreds of metres off. The reference is solved from the global plan, which
  the leaderboard gives both as GNSS and as world locations (the idea of LEAD's ``find_gps_ref``, after
  Bench2DriveZoo), by inverting CARLA's transverse-Mercator mapping (LibCarla ``GeoLocation``).
- The IMU compass is 0 towards north, which is CARLA's -y, and grows clockwise; it can be NaN on the first ticks.
- LEAD steps its route planners with the Kalman-filtered position but moves target points into the ego frame with
  the unfiltered one (two positions per tick); here one position serves both.
- The position filter is filterpy's unscented Kalman filter with LEAD's noise matrices and sigma points; the process
  model is a constant-speed, constant-heading bicycle (LEAD's also feeds the last control through the expert's
  vehicle model, which needs the controller's state; the difference lies within one 50 ms step).

Poses here are in the *world ISO frame*: CARLA world with y negated (y left, yaw counter-clockwise), at the vehicle
centre, where the GNSS sits. Target points come out in the ISO rear-axle ego frame, as the adapter writes them.
"""

import math
from dataclasses import dataclass

import numpy as np

from lead_s2r.formats.lead_route import RoutePlanner, previous_current_next
from lead_s2r.geometry import CARLA_REAR_AXLE_TO_CENTER, centre_points_to_rear_axle, points_to_local, wrap_angle

#: CARLA's ``EARTH_RADIUS_EQUA`` (LibCarla ``GeoLocation.cpp``), metres.
EARTH_RADIUS_EQUA = 6378137.0
#: Fixed-point iterations for the geo reference (the Mercator scale depends on the unknown latitude; 5 reach 1 mm).
GEO_REFERENCE_ITERATIONS = 8
#: ``route_planner_min_distance`` of LEAD's sensor agent, and the planner used when target points are dense.
POP_DISTANCE = 5.0
DENSE_POP_DISTANCE = 4.0
#: Target points closer than this to each other and to the ego count as dense (``sensor_agent_pop_distance_adaptive``).
DENSE_DISTANCE = 10.0
#: A next target point farther than this is replaced by the current one (``sensor_agent_skip_distant_target_point``).
DISTANT_NEXT = 50.0
#: LEAD's UKF: initial covariance, measurement and process noise (x, y, yaw, speed), Merwe sigma-point parameters.
UKF_P = (0.5, 0.5, 1e-6, 1e-6)
UKF_R = (0.5, 0.5, 1e-15, 1e-15)
UKF_Q = (1e-4, 1e-4, 1e-3, 1e-3)
UKF_ALPHA, UKF_BETA, UKF_KAPPA = 1e-5, 2.0, 0.0


@dataclass(frozen=True)
class GeoReference:
    """The latitude / longitude (degrees) of CARLA's world origin."""

    lat: float
    lon: float


def _mercator(lat: np.ndarray, lon: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    mx = scale * np.radians(lon) * EARTH_RADIUS_EQUA
    my = scale * EARTH_RADIUS_EQUA * np.log(np.tan((90.0 + np.asarray(lat)) * np.pi / 360.0))
    return mx, my


def gnss_to_world(lat: np.ndarray, lon: np.ndarray, reference: GeoReference) -> np.ndarray:
    """GNSS degrees -> CARLA world (x, y-right) metres, exactly inverting CARLA's location-to-geo mapping."""
    scale = math.cos(math.radians(reference.lat))
    mx, my = _mercator(np.asarray(lat, np.float64), np.asarray(lon, np.float64), scale)
    mx0, my0 = _mercator(np.array(reference.lat), np.array(reference.lon), scale)
    return np.stack([mx - mx0, -(my - my0)], axis=-1)


def estimate_geo_reference(gnss: np.ndarray, world: np.ndarray) -> GeoReference:
    """The reference that maps ``gnss`` (N, 2) lat/lon onto CARLA ``world`` (N, 2) x/y, median over the pairs."""
    gnss, world = np.asarray(gnss, np.float64), np.asarray(world, np.float64)
    if gnss.shape != world.shape or gnss.ndim != 2 or gnss.shape[1] != 2 or not len(gnss):
        raise ValueError(f"need matching (N, 2) GNSS and world points, got {gnss.shape} and {world.shape}")
    lat, lon = gnss[:, 0], gnss[:, 1]
    lat0, lon0 = lat.copy(), lon.copy()
    for _ in range(GEO_REFERENCE_ITERATIONS):
        scale = np.cos(np.radians(lat0))
        radius = scale * EARTH_RADIUS_EQUA
        lon0 = lon - np.degrees(world[:, 0] / radius)
        log_tan = np.log(np.tan((90.0 + lat) * np.pi / 360.0)) + world[:, 1] / radius
        lat0 = 360.0 * np.arctan(np.exp(log_tan)) / np.pi - 90.0
    return GeoReference(float(np.median(lat0)), float(np.median(lon0)))


def compass_to_yaw(compass: float) -> float:
    """IMU compass (radians, 0 = north = CARLA -y, clockwise) -> world ISO yaw; NaN (first ticks) counts as north."""
    compass = 0.0 if math.isnan(compass) else compass
    return float(wrap_angle(math.pi / 2 - compass))


class PositionFilter:
    """filterpy's unscented Kalman filter on (x, y, yaw, speed) with LEAD's noise settings; yaw residuals wrap."""

    def __init__(self, dt: float) -> None:
        try:
            from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
        except ImportError as err:
            raise ImportError(
                "the closed-loop position filter needs filterpy: pip install 'lead-s2r[carla]' "
                "(or set use_kalman_filter: false)"
            ) from err
        points = MerweScaledSigmaPoints(
            n=4, alpha=UKF_ALPHA, beta=UKF_BETA, kappa=UKF_KAPPA, sqrt_method=_psd_sqrt, subtract=_residual
        )
        self.ukf = UnscentedKalmanFilter(
            dim_x=4, dim_z=4, dt=dt, fx=_move, hx=lambda x: x, points=points,
            x_mean_fn=_mean, z_mean_fn=_mean, residual_x=_residual, residual_z=_residual,
        )  # fmt: skip
        self.ukf.P, self.ukf.R, self.ukf.Q = np.diag(UKF_P), np.diag(UKF_R), np.diag(UKF_Q)
        self.started = False

    def step(self, measurement: np.ndarray) -> np.ndarray:
        """Filtered (x, y, yaw, speed) after one measurement of the same four."""
        measurement = np.asarray(measurement, np.float64)
        if not self.started:
            self.ukf.x, self.started = measurement.copy(), True
            return measurement
        self.ukf.predict()
        self.ukf.update(measurement)
        return self.ukf.x.copy()


def _psd_sqrt(matrix: np.ndarray) -> np.ndarray:
    """A square root of a covariance that rounding left barely indefinite (yaw and speed variances near 1e-15
    make Cholesky fail): eigenvalues clipped at 0; ``S.T @ S`` is the matrix, as filterpy's Cholesky gives."""
    values, vectors = np.linalg.eigh((matrix + matrix.T) / 2)
    return (vectors * np.sqrt(np.clip(values, 0.0, None))).T


def _move(state: np.ndarray, dt: float) -> np.ndarray:
    x, y, yaw, speed = state
    return np.array([x + speed * math.cos(yaw) * dt, y + speed * math.sin(yaw) * dt, yaw, speed])


def _residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    out[2] = wrap_angle(out[2])
    return out


def _mean(sigmas: np.ndarray, weights: np.ndarray) -> np.ndarray:
    out = weights @ sigmas
    out[2] = math.atan2(weights @ np.sin(sigmas[:, 2]), weights @ np.cos(sigmas[:, 2]))
    return out


@dataclass(frozen=True)
class Navigation:
    """Previous / current / next target point (3, 2) in the ISO rear-axle ego frame, and the RoadOptions of the
    previous point (``command``, what the model is told) and of the current one (``next_command``)."""

    target_points: np.ndarray
    command: int
    next_command: int


def dense(points: np.ndarray) -> bool:
    """LEAD's dense-points test on (previous, current, next) in the ego frame."""
    previous, current, following = points
    near = min(np.linalg.norm(previous), np.linalg.norm(current)) < DENSE_DISTANCE
    return near and (
        np.linalg.norm(current - following) < DENSE_DISTANCE or np.linalg.norm(previous - current) < DENSE_DISTANCE
    )


class TargetPoints:
    """LEAD's sensor-agent target points: the 5 m planner, the 4 m one when the points are dense (``adaptive``), and
    the current point for a next one beyond 50 m (``skip_distant``); both planners step every tick, as LEAD's."""

    def __init__(
        self, points: np.ndarray, commands: list[int], adaptive: bool = True, skip_distant: bool = True
    ) -> None:
        self.planner = RoutePlanner(points, commands, POP_DISTANCE)
        self.dense_planner = RoutePlanner(points, commands, DENSE_POP_DISTANCE)
        self.adaptive, self.skip_distant = adaptive, skip_distant

    def step(self, pose: np.ndarray) -> Navigation:
        """Navigation for the ego at world ISO ``pose`` (x, y, yaw) of its vehicle centre."""
        route, dense_route = self.planner.step(pose), self.dense_planner.step(pose)
        points, commands = previous_current_next(route)
        points = points_to_local(points, pose)
        if self.adaptive and dense(points):
            points, commands = previous_current_next(dense_route)
            points = points_to_local(points, pose)
        if self.skip_distant and np.linalg.norm(points[2]) > DISTANT_NEXT:
            points[2] = points[1]
        target_points = centre_points_to_rear_axle(points, CARLA_REAR_AXLE_TO_CENTER)
        return Navigation(target_points.astype(np.float32), int(commands[0]), int(commands[1]))


def road_option(value: object) -> int:
    """A RoadOption (the leaderboard's enum, or its int value) as an int."""
    return int(getattr(value, "value", value))
