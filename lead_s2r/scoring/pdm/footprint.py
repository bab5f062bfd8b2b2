"""Boxes as corner arrays and shapely polygons, in nuPlan's corner order (``BBCoordsIndex``).

The order is not cosmetic: NC's front-bumper test takes the polygon's exterior coordinates 0 and 3 (front left to
front right), and the polygon ring is closed by repeating the front-left corner in the centre's slot, exactly as
``pdm_array_representation.coords_array_to_polygon_array`` does. Corners come from nuPlan's
``translate_lon_and_lat`` (a lateral offset along ``heading + pi/2``), so footprints agree with NAVSIM to the last bit.
"""

from enum import IntEnum

import numpy as np
import shapely

from lead_s2r.scoring.pdm.state import StateIndex
from lead_s2r.scoring.pdm.vehicle import VehicleParameters

#: a box's length or width: one for all boxes or one per box (broadcast against the headings)
Size = np.ndarray | float


class Corner(IntEnum):
    """Rows of a ``(..., 5, 2)`` box array (nuPlan ``BBCoordsIndex``)."""

    FRONT_LEFT = 0
    REAR_LEFT = 1
    REAR_RIGHT = 2
    FRONT_RIGHT = 3
    CENTER = 4


def _boxes(
    x: np.ndarray, y: np.ndarray, headings: np.ndarray, along: tuple[np.ndarray, np.ndarray], length: Size, width: Size
) -> np.ndarray:
    """``(..., 5, 2)`` corners and centre of boxes of centre ``(x, y)``, heading ``headings`` (``along``: its cosine
    and sine) and size: each corner moved ``lon`` along the heading and ``lat`` across it (nuPlan's
    ``translate_lon_and_lat``), x and y apart (numpy's loops over an axis of 2 cost far more)."""
    half_length, half_width = np.asarray(length) / 2.0, np.asarray(width) / 2.0
    across = headings + np.pi / 2.0
    cos_across, sin_across = np.cos(across), np.sin(across)
    cos_along, sin_along = along
    coords = np.empty((*headings.shape, len(Corner), 2))
    coords[..., Corner.CENTER, 0] = x
    coords[..., Corner.CENTER, 1] = y
    for corner, lon, lat in (
        (Corner.FRONT_LEFT, half_length, half_width),
        (Corner.REAR_LEFT, -half_length, half_width),
        (Corner.REAR_RIGHT, -half_length, -half_width),
        (Corner.FRONT_RIGHT, half_length, -half_width),
    ):
        coords[..., corner, 0] = x + (lat * cos_across + lon * cos_along)
        coords[..., corner, 1] = y + (lat * sin_across + lon * sin_along)
    return coords


def box_coords(centers: np.ndarray, headings: np.ndarray, length: Size, width: Size) -> np.ndarray:
    """``(..., 5, 2)`` corners and centre of boxes given by centre ``(..., 2)``, heading ``(...)`` and size."""
    return _boxes(centers[..., 0], centers[..., 1], headings, (np.cos(headings), np.sin(headings)), length, width)


def heading_directions(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cosine and sine ``(N, T)`` of the headings of rear-axle states ``(N, T, 11)``: the ego boxes and TTC's moves
    along the heading share them."""
    headings = states[..., StateIndex.HEADING]
    return np.cos(headings), np.sin(headings)


def ego_coords(
    states: np.ndarray, vehicle: VehicleParameters, along: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """Ego boxes ``(N, T, 5, 2)`` from rear-axle states ``(N, T, 11)``: centre ``rear_axle_to_center`` ahead.
    ``along``: the states' :func:`heading_directions` where the caller has them."""
    headings = states[..., StateIndex.HEADING]
    shift = vehicle.rear_axle_to_center
    cos, sin = heading_directions(states) if along is None else along
    x, y = states[..., StateIndex.X] + shift * cos, states[..., StateIndex.Y] + shift * sin
    return _boxes(x, y, headings, (cos, sin), vehicle.length, vehicle.width)


def box_polygons(coords: np.ndarray) -> np.ndarray:
    """Shapely polygons ``(...)`` of boxes ``(..., 5, 2)``; the ring is closed through the front-left corner."""
    ring = coords.copy()
    ring[..., Corner.CENTER, :] = ring[..., Corner.FRONT_LEFT, :]
    return shapely.polygons(ring)
