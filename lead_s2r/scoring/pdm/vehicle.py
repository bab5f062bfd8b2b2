"""Ego vehicle geometry for the PDM score: nuPlan's Chrysler Pacifica, the car every NAVSIM log was driven with."""

from dataclasses import dataclass


@dataclass(frozen=True)
class VehicleParameters:
    """Box of the ego around its rear axle; all NAVSIM states are rear-axle states."""

    width: float
    front_length: float
    rear_length: float
    wheel_base: float
    height: float

    @property
    def length(self) -> float:
        return self.front_length + self.rear_length

    @property
    def rear_axle_to_center(self) -> float:
        """Distance from the rear axle forward to the box centre (nuPlan: half length minus rear length)."""
        return self.length / 2 - self.rear_length


#: nuPlan ``get_pacifica_parameters()``: 5.176 m x 2.297 m, rear axle 1.461 m behind the centre.
PACIFICA = VehicleParameters(width=2.297, front_length=4.049, rear_length=1.127, wheel_base=3.089, height=1.777)
