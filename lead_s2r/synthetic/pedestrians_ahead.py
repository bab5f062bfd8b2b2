"""The scene that needs perception, shared by the synthetic NAVSIM, WOD-E2E and CARLA worlds: pedestrians stand
across the ego lane ahead, and the driver brakes smoothly to a stop :data:`GAP` behind them.

The driver cruises (constant acceleration, as in every other log) until ``brake_at`` and then follows a half-cosine
speed ramp down to a standstill. Nothing before ``brake_at`` differs from a log without pedestrians, so a model that
sees only the ego status cannot tell the two apart until the braking has begun: the worlds put ``brake_at`` after
the frames they score, so only the cameras (and, in CARLA, the boxes) show why the driver stops.
"""

import math

import numpy as np

#: The ego's front bumper stops this far (m) behind the pedestrians.
GAP = 3.0
#: The braking of a speed v lasts T = max(MIN_DURATION, v / RATE) seconds: a peak deceleration pi/2 * v / T of at
#: most 3.9 m/s^2 and a peak jerk pi^2/2 * v / T^2 of at most 3.5 m/s^3, inside NAVSIM's comfort bounds (4.05, 4.13).
MIN_DURATION = 3.5
RATE = 2.5
#: Lateral offsets (m, left of the lane centre) of the pedestrians across the lane, and each one's box (length,
#: width, height): a row nearly as wide as the lane and taller than a car, drawn in :data:`COLOUR` (BGR, bright
#: yellow, at least 8 grey levels from 0 and 255 for the cameras' pixel noise; far from the sky, road, grass and
#: vehicle colours), so it stands out at 20-40 m in a 192-pixel strip.
ROW = (-1.4, -0.7, 0.0, 0.7, 1.4)
SIZE = (0.6, 0.6, 1.8)
COLOUR = (20, 210, 240)


def brake_duration(speed: float) -> float:
    """How long (s) the driver takes to brake to a stop from ``speed`` (m/s)."""
    return max(MIN_DURATION, speed / RATE)


def motion(
    speed: float, accel: float, brake_at: float | None, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance travelled (m), speed and acceleration at times ``t`` (s) of a driver starting at ``speed`` with
    constant ``accel``, braking to a stop from ``brake_at`` (None: never)."""
    t = np.asarray(t, np.float64)
    travelled, velocity = speed * t + 0.5 * accel * t**2, speed + accel * t
    acceleration = np.full_like(t, accel)
    if brake_at is None:
        return travelled, velocity, acceleration
    v_b, s_b = speed + accel * brake_at, speed * brake_at + 0.5 * accel * brake_at**2
    duration = brake_duration(v_b)
    tau = np.clip(t - brake_at, 0.0, duration)
    phase = math.pi * tau / duration
    braking = t > brake_at
    travelled = np.where(braking, s_b + v_b / 2 * (tau + duration / math.pi * np.sin(phase)), travelled)
    velocity = np.where(braking, v_b / 2 * (1 + np.cos(phase)), velocity)
    acceleration = np.where(braking, -v_b * math.pi / (2 * duration) * np.sin(phase), acceleration)
    return travelled, velocity, acceleration


def stopping_distance(speed: float, accel: float, brake_at: float) -> float:
    """How far (m) the driver of :func:`motion` travels before it stands still."""
    v_b = speed + accel * brake_at
    return speed * brake_at + 0.5 * accel * brake_at**2 + v_b / 2 * brake_duration(v_b)


def row_distance(stop: float, ego_front: float) -> float:
    """Distance (m) from the ego's reference point at the start to the row's centre, for an ego that stops after
    ``stop`` metres and whose front bumper is ``ego_front`` ahead of its reference point."""
    return stop + ego_front + GAP + SIZE[0] / 2
