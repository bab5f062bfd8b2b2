"""The grids a model plans and perceives on (output trajectory grids, the BEV raster) and the ego-status MLP's
configuration: plain types, so LightningCLI reads them from YAML and checkpoints store them. The TransFuser family's
own configuration is LEAD's (:mod:`lead_s2r.models.lead_config`)."""

import math
from dataclasses import dataclass, field
from typing import NamedTuple

#: Vertical field of view of LEAD's NAVSIM camera rig (nuPlan's 63.71 deg across 480 px, 270 of 280 rows kept), deg.
NAVSIM_VERTICAL_FOV_DEG = 2 * math.degrees(math.atan(math.tan(math.radians(63.71 / 2)) * 270 / 480))


class TrajectoryGrid(NamedTuple):
    """A dataset's output grid: ``num_points`` poses at ``t = dt, 2 dt, ...`` seconds (a NamedTuple, not a dataclass,
    so LightningCLI can write it back into saved configs inside a dict)."""

    num_points: int
    dt: float

    @property
    def times(self) -> tuple[float, ...]:
        return tuple(self.dt * (i + 1) for i in range(self.num_points))


@dataclass(frozen=True)
class BEVGrid:
    """Bird's-eye-view raster in the ISO ego frame: axis H runs along +x (row ``i`` covers ``x_min + i / ppm``), axis W
    along +y (column ``j`` covers ``y_min + j / ppm``): index order follows coordinate order, so no flip hides in it."""

    x_min: float = -32.0
    x_max: float = 64.0
    y_min: float = -40.0
    y_max: float = 40.0
    pixels_per_meter: float = 4.0

    @property
    def shape(self) -> tuple[int, int]:
        return (
            round((self.x_max - self.x_min) * self.pixels_per_meter),
            round((self.y_max - self.y_min) * self.pixels_per_meter),
        )


#: LEAD's CARLA leaderboard BEV box (x in [-32, 64], y in [-40, 40], 4 px/m -> 384 x 320).
CARLA_BEV = BEVGrid()
#: NAVSIM's +-32 m square (256 x 256).
NAVSIM_BEV = BEVGrid(-32.0, 32.0, -32.0, 32.0)


def default_grids() -> dict[str, TrajectoryGrid]:
    """LEAD's output grids: CARLA 8 @ 4 Hz, NAVSIM 8 @ 2 Hz, WOD-E2E 10 @ 2 Hz."""
    return {"carla": TrajectoryGrid(8, 0.25), "navsim": TrajectoryGrid(8, 0.5), "wod": TrajectoryGrid(10, 0.5)}


@dataclass
class EgoMLPConfig:
    """The ego-status MLP baseline (NAVSIM's EgoStatusMLP): speed, acceleration, command -> trajectory."""

    hidden: int = 512
    layers: int = 3
    num_commands: int = 4
    max_speed: float = 20.0
    max_acceleration: float = 4.0
    trajectory_grids: dict[str, TrajectoryGrid] = field(default_factory=default_grids)
