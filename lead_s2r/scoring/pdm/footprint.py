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


class Corner(IntEnum):
    """Rows of a ``(..., 5, 2)`` box array (nuPlan ``BBCoordsIndex``)."""

    FRONT_LEFT = 0
    REAR_LEFT = 1
    REAR_RIGHT = 2
    FRONT_RIGHT = 3
    CENTER = 4


def _translate(
    centers: np.ndarray, turns: tuple[np.ndarray, ...], lon: np.ndarray | float, lat: np.ndarray | float
) -> np.ndarray:
    """``centers`` moved ``lon`` along the heading and ``lat`` across it; ``turns``: the cosine and sine of the
    heading plus pi/2 and of the heading (computed once for the four corners)."""
    cos_across, sin_across, cos_along, sin_along = turns
    offset = np.stack([lat * cos_across + lon * cos_along, lat * sin_across + lon * sin_along], axis=-1)
    return centers + offset


def box_coords(
    centers: np.ndarray, headings: np.ndarray, length: np.ndarray | float, width: np.ndarray | float
) -> np.ndarray:
    """``(..., 5, 2)`` corners and centre of boxes given by centre ``(..., 2)``, heading ``(...)`` and size."""
    half_length, half_width = np.asarray(length) / 2.0, np.asarray(width) / 2.0
    across = headings + np.pi / 2.0
    turns = (np.cos(across), np.sin(across), np.cos(headings), np.sin(headings))
    coords = np.empty((*headings.shape, len(Corner), 2))
    coords[..., Corner.CENTER, :] = centers
    coords[..., Corner.FRONT_LEFT, :] = _translate(centers, turns, half_length, half_width)
    coords[..., Corner.REAR_LEFT, :] = _translate(centers, turns, -half_length, half_width)
    coords[..., Corner.REAR_RIGHT, :] = _translate(centers, turns, -half_length, -half_width)
    coords[..., Corner.FRONT_RIGHT, :] = _translate(centers, turns, half_length, -half_width)
    return coords


def ego_coords(states: np.ndarray, vehicle: VehicleParameters) -> np.ndarray:
    """Ego boxes ``(N, T, 5, 2)`` from rear-axle states ``(N, T, 11)``: centre ``rear_axle_to_center`` ahead."""
    headings = states[..., StateIndex.HEADING]
    shift = vehicle.rear_axle_to_center
    centers = states[..., StateIndex.X : StateIndex.Y + 1] + np.stack(
        [shift * np.cos(headings), shift * np.sin(headings)], -1
    )
    return box_coords(centers, headings, vehicle.length, vehicle.width)


def box_polygons(coords: np.ndarray) -> np.ndarray:
    """Shapely polygons ``(...)`` of boxes ``(..., 5, 2)``; the ring is closed through the front-left corner."""
    ring = coords.copy()
    ring[..., Corner.CENTER, :] = ring[..., Corner.FRONT_LEFT, :]
    return shapely.polygons(ring)
