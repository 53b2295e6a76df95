"""Field paths read numbers out of decoded messages of any shape."""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from blackbox.observe.fieldpath import compile_field_access, compile_field_path


@dataclass
class Point:
    x: float
    y: float


def test_single_field_on_attribute_object() -> None:
    assert compile_field_path("data")(SimpleNamespace(data=15.5)) == 15.5


def test_nested_attributes() -> None:
    msg = SimpleNamespace(pose=SimpleNamespace(position=SimpleNamespace(x=1.25, y=0.0)))
    assert compile_field_path("pose.position.x")(msg) == 1.25


def test_dicts_and_lists_as_from_json() -> None:
    msg = {"points": [{"x": 1.0}, {"x": 2.5}], "ranges": [0.5, 0.75, 1.0, 4.0]}
    assert compile_field_path("points[1].x")(msg) == 2.5
    assert compile_field_path("ranges[3]")(msg) == 4.0
    assert compile_field_path("ranges[-1]")(msg) == 4.0


def test_dataclasses_and_numpy_arrays() -> None:
    msg = SimpleNamespace(points=[Point(1.0, 2.0)], ranges=np.array([0.5, 1.5], dtype=np.float32))
    assert compile_field_path("points[0].y")(msg) == 2.0
    value = compile_field_path("ranges[1]")(msg)
    assert value == 1.5 and type(value) is float


def test_nested_indices() -> None:
    msg = SimpleNamespace(grid=[[1, 2], [3, 4]])
    assert compile_field_path("grid[1][0]")(msg) == 3.0


def test_integers_booleans_and_numpy_scalars_are_numbers() -> None:
    f = compile_field_path("data")
    assert f(SimpleNamespace(data=7)) == 7.0
    assert f(SimpleNamespace(data=True)) == 1.0
    assert f(SimpleNamespace(data=np.int16(-3))) == -3.0
    assert f(SimpleNamespace(data=np.bool_(False))) == 0.0
    assert f(SimpleNamespace(data=np.array(2.5))) == 2.5


def test_nan_is_returned_for_the_observer_to_judge() -> None:
    assert np.isnan(compile_field_path("data")(SimpleNamespace(data=float("nan"))))


def test_missing_field_names_the_step() -> None:
    f = compile_field_path("pose.position.x")
    with pytest.raises(ValueError, match=r"'pose.position.x': pose has no field 'position'"):
        f(SimpleNamespace(pose=SimpleNamespace(orientation=None)))
    with pytest.raises(ValueError, match="message has no field 'pose'"):
        f({"header": {}})


def test_index_out_of_range() -> None:
    with pytest.raises(ValueError, match="index 3 out of range for ranges"):
        compile_field_path("ranges[3]")(SimpleNamespace(ranges=[1.0, 2.0]))


def test_index_into_a_scalar() -> None:
    with pytest.raises(ValueError, match=r"ranges is float 1\.0, cannot take \[0\]"):
        compile_field_path("ranges[0]")(SimpleNamespace(ranges=1.0))


def test_strings_are_not_numbers() -> None:
    with pytest.raises(ValueError, match=r"value is str '15\.0', not a number"):
        compile_field_path("data")(SimpleNamespace(data="15.0"))
    with pytest.raises(ValueError, match="not a number"):
        compile_field_path("data")(SimpleNamespace(data=[1.0]))


@pytest.mark.parametrize("path", ["", "  ", "a..b", ".a", "a.", "a[x]", "a[1", "1a", "a b"])
def test_malformed_paths_fail_at_compile_time(path: str) -> None:
    with pytest.raises(ValueError):
        compile_field_path(path)


def test_raw_access_returns_sub_messages() -> None:
    stamp = SimpleNamespace(sec=3, nanosec=5)
    assert compile_field_access("header.stamp")({"header": {"stamp": stamp}}) is stamp
