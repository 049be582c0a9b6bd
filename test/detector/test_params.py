"""What MradParams accepts: any integer type for an integer, any real type for a real, and a
choice or a flag only in its own type."""

import json
from fractions import Fraction

import numpy as np
import pytest

from allo_mrad_ros.detector.params import (
    PARAMETER_SPECS,
    MradParams,
    ParamsError,
    coerce_value,
    params_from,
    profile,
)


@pytest.mark.parametrize("integer", [np.int64(8), np.int32(8), np.uint8(8), np.intp(8)])
def test_any_integer_type_is_an_integer(integer):
    params = MradParams(grid=integer)
    assert params == MradParams(grid=8)
    # Stored as a plain int: the stages and a JSON report see what a literal 8 gives.
    assert type(params.grid) is int
    assert json.loads(json.dumps(params.to_dict()))["grid"] == 8


def test_an_integer_choice_takes_any_integer_type():
    params = MradParams(connectivity=np.int16(4), transfer_bin=np.int64(32))
    assert (params.connectivity, params.transfer_bin) == (4, 32)
    assert type(params.connectivity) is int and type(params.transfer_bin) is int


@pytest.mark.parametrize(
    "real", [30, np.int64(30), np.float32(30.0), np.float64(30.0), Fraction(30)]
)
def test_any_real_type_is_a_real(real):
    params = MradParams(tolerance=real)
    assert params.tolerance == 30.0
    assert type(params.tolerance) is float


def test_a_numpy_bool_is_a_flag():
    params = MradParams(transfer_gain=np.bool_(False))
    assert params.transfer_gain is False


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"connectivity": 8.0}, r"connectivity must be an integer one of \[4, 8\], got 8.0"),
        ({"connectivity": np.float64(4.0)}, r"connectivity must be an integer one of \[4, 8\]"),
        ({"connectivity": True}, r"connectivity must be an integer"),
        ({"transfer_bin": 16.0}, r"transfer_bin must be an integer one of \[4, 8, 16, 32, 64\]"),
        ({"transfer_gain": 1}, r"transfer_gain must be true or false, got 1"),
        ({"transfer_gain": np.int64(0)}, r"transfer_gain must be true or false"),
        ({"transfer_gain": "true"}, r"transfer_gain must be true or false, got 'true'"),
        ({"grid": 8.0}, r"grid must be an integer in \[1, 64\], got 8.0"),
        ({"grid": True}, r"grid must be an integer in \[1, 64\], got True"),
        ({"grid": np.float32(8)}, r"grid must be an integer"),
        ({"tolerance": True}, r"tolerance must be a number, got True"),
        ({"tolerance": np.bool_(True)}, r"tolerance must be a number"),
        ({"tolerance": "30"}, r"tolerance must be a number, got '30'"),
        ({"score_scaling": b"fixed"}, r"score_scaling must be one of \['fixed', 'per_image'\]"),
        ({"score_scaling": 1}, r"score_scaling must be one of"),
        ({"grid": np.int64(65)}, r"grid must be an integer in \[1, 64\], got 65"),
    ],
)
def test_a_value_of_the_wrong_type_is_refused_naming_it(changes, message):
    with pytest.raises(ParamsError, match=message):
        MradParams(**changes)
    # ParamsError is a ValueError, what callers of MradParams have always caught.
    with pytest.raises(ValueError, match=message):
        MradParams().replace(**changes)


def test_every_default_has_its_parameter_type():
    params = MradParams()
    for name, spec in PARAMETER_SPECS.items():
        assert type(getattr(params, name)) is spec.kind, name


def test_parameters_from_text_and_numbers_have_one_coercion():
    assert params_from("accurate", ["grid=3", "tolerance=30"]) == MradParams(
        process_scale=1.0, grid=3, tolerance=30.0
    )
    assert params_from("paper", ["grid=6"]) == profile("paper", grid=6)
    assert params_from("default", {"tolerance": 30}).tolerance == 30.0
    assert params_from("default", ["transfer_gain=False"]).transfer_gain is False
    for bad, message in (
        (["grid=two"], "not a valid int"),
        (["nope=1"], "KEY=VALUE"),
        (["grid=0"], "grid"),
        ({"grid": 2.5}, "integer"),
        (["transfer_gain=1"], "not true or false"),
        (["connectivity=8.0"], "not a valid int"),
    ):
        with pytest.raises(ParamsError, match=message):
            params_from("default", bad)
    with pytest.raises(ParamsError, match="unknown MRAD profile 'x'"):
        params_from("x")


def test_coerce_value_returns_the_parameter_type():
    spec = PARAMETER_SPECS["tolerance"]
    assert type(coerce_value("mrad.tolerance", spec, 30)) is float  # a ROS integer
    assert coerce_value("mrad.tolerance", spec, " 30 ") == 30.0
    assert type(coerce_value("mrad.grid", PARAMETER_SPECS["grid"], np.int64(4))) is int
    with pytest.raises(ParamsError, match=r"mrad.grid must be an integer in \[1, 64\], got 0"):
        coerce_value("mrad.grid", PARAMETER_SPECS["grid"], "0")
