"""lead_s2r.fields: the one typed-fields check every file reader uses (bool is no number, null only where optional)."""

import math
from typing import Literal

import numpy as np
import pytest

from lead_s2r.errors import UserError
from lead_s2r.fields import check_fields, describe, fits, is_number


@pytest.mark.parametrize(
    ("value", "hint", "expected"),
    [
        (3, int, True),
        (True, int, False),  # YAML's `true` is no count
        (3.0, int, False),
        (np.int64(3), int, True),
        (3, float, True),  # JSON writes 3.0 as 3
        (False, float, False),
        (math.nan, float, False),
        (math.inf, float, False),
        (np.float32(0.5), float, True),
        (1, bool, False),  # `creeping: 1` is no switch
        (True, bool, True),
        (None, str | None, True),
        (None, str, False),
        ("route", Literal["route", "waypoint"], True),
        ("pid", Literal["route", "waypoint"], False),
        (True, Literal[1], False),
        ([1, 2], list[int], True),
        ([1, True], list[int], False),
        ([0.5, 2], list[float], True),
        ("ab", list[str], False),
        ({"a": 1}, dict, True),
        (7, dict, False),
    ],
)
def test_fits(value: object, hint: object, expected: bool) -> None:
    assert fits(value, hint) is expected


def test_is_number_keeps_nan_only_when_asked() -> None:
    assert is_number(math.nan, finite=False) and not is_number(math.nan)
    assert not is_number(True, finite=False) and not is_number("1", finite=False)


def test_describe_says_the_type_in_words() -> None:
    assert describe(int) == "int"
    assert describe(str | None) == "str or null"
    assert describe(Literal["route", "waypoint"]) == "one of 'route', 'waypoint'"
    assert describe(list[float]) == "a list of float"


def test_check_fields_names_where_field_value_and_type() -> None:
    hints = {"seeds": list[int], "title": str}
    mapping = {"seeds": [0, 1], "other": object()}  # fields without a hint are the caller's business
    assert check_fields(mapping, hints, "t.yaml") is mapping
    with pytest.raises(UserError, match=r"^t\.yaml: seeds is \[0, True\], not a list of int; see the docs$"):
        check_fields({"seeds": [0, True]}, hints, "t.yaml", advice="see the docs")
    with pytest.raises(UserError, match=r"^t\.yaml: rows\[1\]\.seeds is \[0\.5\], not a list of int$"):
        check_fields({"seeds": [0.5]}, hints, "t.yaml", at="rows[1]")
    with pytest.raises(ValueError, match=r"^t\.yaml: the file is 7, not a mapping$"):
        check_fields(7, hints, "t.yaml", ValueError)


def test_check_fields_names_the_first_required_field_missing() -> None:
    hints = {"metric": str}
    assert check_fields({"metric": "ade"}, hints, "s.json", required=("metric",)) == {"metric": "ade"}
    with pytest.raises(UserError, match=r"^s\.json: missing field 'metric'; rescore$"):
        check_fields({"tag": None}, hints, "s.json", advice="rescore", required=("metric", "tag"))
    with pytest.raises(UserError, match=r"^r\.json: records\[0\]: missing field 'meta'$"):
        check_fields({}, {}, "r.json", at="records[0]", required=("meta",))
