import numpy as np
import pytest
from toy_adapter import toy_sample

from lead_s2r.schema import Command, SchemaError, command4, make_key, validate


def test_valid_sample_passes():
    validate(toy_sample("log000", 3))


def _broken(mutate):
    sample = toy_sample("log000", 3)
    mutate(sample)
    return sample


CASES = {
    "key with a dot": (lambda s: s.update(__key__="a.b"), "__key__"),
    "missing past": (lambda s: s.pop("past"), "past"),
    "wrong dtype": (lambda s: s.update(future=s["future"].astype(np.float64)), "future"),
    "wrong shape": (lambda s: s.update(boxes=np.zeros((2, 9), np.float32)), "boxes"),
    "NaN in x": (lambda s: s["future"].__setitem__((2, 1), np.nan), "future"),
    "t not increasing": (lambda s: s["future"].__setitem__((3, 0), 0.1), "future"),
    "past not ending at 0": (lambda s: s["past"].__setitem__((-1, 0), -0.1), "past"),
    "future with t <= 0": (lambda s: s["future"].__setitem__((0, 0), 0.0), "future"),
    "yaw out of range": (lambda s: s["future"].__setitem__((1, 3), 4.0), "future"),
    "unknown field": (lambda s: s.update(weather=np.zeros(1, np.float32)), "weather"),
    "not a JPEG": (lambda s: s.update(cam_front=b"PNG..."), "cam_front"),
    "has flag missing": (lambda s: s["meta"]["has"].pop("lidar"), "meta.has.lidar"),
    "has flag without field": (lambda s: s["meta"]["has"].update(radar=True), "meta.has.radar"),
    "non-finite speed": (lambda s: s["meta"]["ego"].update(speed=float("inf")), "meta.ego.speed"),
    "bad command": (lambda s: s["meta"]["ego"].update(command=42), "meta.ego.command"),
    "missing vehicle entry": (lambda s: s["meta"]["vehicle"].pop("wheel_base"), "meta.vehicle.wheel_base"),
    "wrong schema version": (lambda s: s["meta"].update(schema_version=0), "meta.schema_version"),
    "lidar columns mismatch": (lambda s: s["meta"].update(lidar_columns=["x"]), "meta.lidar_columns"),
    "half-NaN target point": (lambda s: s["target_points"].__setitem__((2, 0), np.nan), "target_points"),
    "NaN box": (lambda s: s["boxes"].__setitem__((0, 0), np.nan), "boxes"),
    "bad camera K": (lambda s: s["meta"]["cameras"][0].update(K=[[1, 0], [0, 1]]), "meta.cameras[0]"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_invalid_sample_names_the_field(case):
    mutate, field = CASES[case]
    with pytest.raises(SchemaError) as err:
        validate(_broken(mutate))
    assert err.value.field == field
    assert repr(field) in str(err.value)


def test_nan_yaw_is_allowed_where_the_source_has_none():
    sample = toy_sample("log000", 3)
    sample["future"][:, 3] = np.nan
    validate(sample)


def test_absent_target_point_row_is_allowed():
    sample = toy_sample("log000", 3)
    sample["target_points"][0] = np.nan
    validate(sample)


def test_command4_projection():
    assert command4(Command.LANE_FOLLOW) is Command.STRAIGHT
    assert command4(Command.CHANGE_LANE_LEFT) is Command.LEFT
    assert command4(Command.CHANGE_LANE_RIGHT) is Command.RIGHT
    assert [command4(c) for c in range(4)] == [Command(c) for c in range(4)]


def test_make_key_has_no_dots():
    key = make_key("navsim", "2021.10.11.08.31.07_veh-50", 12)
    assert "." not in key and key.endswith("_12")
