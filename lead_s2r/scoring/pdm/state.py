"""The 11-entry simulated ego state of NAVSIM's PDM simulator (``StateIndex``), all at the rear axle."""

from enum import IntEnum


class StateIndex(IntEnum):
    """Columns of a ``(..., 11)`` state array: pose in the scene frame, dynamics in the ego body frame."""

    X = 0
    Y = 1
    HEADING = 2
    VELOCITY_X = 3
    VELOCITY_Y = 4
    ACCELERATION_X = 5
    ACCELERATION_Y = 6
    STEERING_ANGLE = 7
    STEERING_RATE = 8
    ANGULAR_VELOCITY = 9
    ANGULAR_ACCELERATION = 10


STATE_SIZE = len(StateIndex)
