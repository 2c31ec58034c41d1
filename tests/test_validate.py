"""The shared argument validators: one exception type per kind of mistake, the argument named."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
import torch

from meshadv import _validate as v


def test_doctests_pass() -> None:
    assert doctest.testmod(v).failed == 0


@pytest.mark.parametrize("value", [1.9, 2.0, "10", None, True, np.bool_(True), torch.tensor(1.0), [1]])
def test_integer_refuses_non_integers_with_type_error(value: object) -> None:
    with pytest.raises(TypeError, match="^steps must be an integer"):
        v.positive_int("steps", value)


@pytest.mark.parametrize("value", [3, np.int64(3), torch.tensor(3), np.array(3)])
def test_integer_accepts_integer_like(value: object) -> None:
    out = v.positive_int("steps", value)
    assert out == 3 and type(out) is int


@pytest.mark.parametrize("value", [0, -1])
def test_positive_int_range_is_value_error(value: int) -> None:
    with pytest.raises(ValueError, match="steps must be an integer >= 1"):
        v.positive_int("steps", value)


def test_seed_and_threads_ranges() -> None:
    assert v.seed("seed", 2**63 - 1) == 2**63 - 1
    with pytest.raises(ValueError, match="seed"):
        v.seed("seed", 2**70)
    with pytest.raises(ValueError, match="seed"):
        v.seed("seed", -1)
    assert v.num_threads("num_threads", 0) == 0
    with pytest.raises(ValueError, match="num_threads"):
        v.num_threads("num_threads", 2**64)
    with pytest.raises(TypeError, match="num_threads"):
        v.num_threads("num_threads", "1")
    with pytest.raises(TypeError, match="num_threads"):
        v.num_threads("num_threads", 1.5)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_finite_float_refuses_non_finite(value: float) -> None:
    with pytest.raises(ValueError, match="lr must be finite"):
        v.finite_float("lr", value)


@pytest.mark.parametrize("value", ["0.1", None, True, 1 + 2j, torch.tensor(1 + 2j)])
def test_finite_float_refuses_wrong_types(value: object) -> None:
    with pytest.raises(TypeError, match="lr must be a real number"):
        v.finite_float("lr", value)


def test_finite_float_bounds() -> None:
    assert v.finite_float("x", 1, low=0, high=1) == 1.0
    assert v.finite_float("x", torch.tensor(0.5)) == 0.5
    with pytest.raises(ValueError, match="x must be a number > 0"):
        v.positive_float("x", 0.0)
    with pytest.raises(ValueError, match="^x must be a number <= 1"):
        v.finite_float("x", 1.5, high=1)


def test_choice_suggests_the_closest_option() -> None:
    assert v.choice("kind", "shape", ("shape", "texture")) == "shape"
    with pytest.raises(ValueError, match="^kind must be one of .*did you mean 'texture'"):
        v.choice("kind", "textur", ("shape", "texture"))
    with pytest.raises(TypeError, match="kind must be one of"):
        v.choice("kind", None, ("shape", "texture"))


def test_index_and_boolean() -> None:
    assert v.index("i", -1, 3) == 2
    with pytest.raises(IndexError, match="i 3 is out of range for length 3"):
        v.index("i", 3, 3)
    with pytest.raises(TypeError, match="i must be an integer index"):
        v.index("i", 1.0, 3)
    assert v.boolean("flag", np.bool_(False)) is False
    with pytest.raises(TypeError, match="flag must be True or False"):
        v.boolean("flag", 1)
