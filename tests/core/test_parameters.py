"""The parameter table is the one list of parameters: the draw, the learning, the schema and the
dataset columns agree with it, and normalization keeps the numbers it always had."""

import math

import numpy as np
import pytest
import yaml

from forcdecode.config import SCHEMA_PATH
from forcdecode.core.parameters import (BY_NAME, DEFAULT_BOUNDS, LOG_SCALE, NAMES, PARAMETERS, TARGETS, UNITS,
                                        Parameter, denormalize, normalize)


def test_table():
    assert NAMES == ("Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K")
    assert TARGETS == ("N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K")
    assert set(TARGETS) == {p.name for p in PARAMETERS if p.learned} and not BY_NAME["Ms"].learned
    assert LOG_SCALE == {"K_u"}
    assert DEFAULT_BOUNDS == {"Ms": [2e5, 1.4e6], "A_ex": [1e-12, 35e-12], "K_u": [1e3, 1.5e6], "D": [0.0, 5e-3],
                              "N_pin": [0, 255], "sigma_theta_deg": [0.0, 10.0], "sigma_K": [0.0, 0.2]}
    assert UNITS["K_u"] == "J/m^3" and UNITS["Ms"] == "A/m"
    with pytest.raises(ValueError, match="scale"):
        Parameter("x", "1", 0, 1, "cubic", "", False)
    with pytest.raises(ValueError, match="low < high"):
        Parameter("x", "1", 1, 1, "linear", "", False)


def test_normalization_numbers():
    assert normalize("Ms", 8e5) == pytest.approx(0.5)
    assert normalize("K_u", math.sqrt(1e3 * 1.5e6)) == pytest.approx(0.5)  # log scale: geometric midpoint
    assert denormalize("K_u", 0.0) == pytest.approx(1e3) and denormalize("K_u", 1.0) == pytest.approx(1.5e6)
    assert normalize("N_pin", 4, {"N_pin": [0, 4]}) == 1.0  # configured bounds, not the table's
    u = np.linspace(0, 1, 7)
    for name in NAMES:
        assert np.allclose(normalize(name, denormalize(name, u)), u)
    with pytest.raises(KeyError, match="unknown parameter"):
        normalize("Hk", 1.0)


def test_schema_names_the_table():
    schema = yaml.safe_load(SCHEMA_PATH.read_text())
    pattern = next(iter(schema["properties"]["bounds"]["patternProperties"]))
    assert set(pattern.strip("^$()").split("|")) == set(NAMES)
    learning = schema["properties"]["learning"]["properties"]["parameters"]
    assert tuple(learning["items"]["enum"]) == TARGETS and tuple(learning["default"]) == TARGETS


def test_everyone_reads_the_table():
    from forcdecode.dataset import merge, params
    from forcdecode.learn import data

    assert params.PARAMETERS == NAMES and merge.PARAMETERS == NAMES
    assert data.TARGETS is TARGETS and data.UNITS is UNITS
    assert params.DEFAULT_BOUNDS is DEFAULT_BOUNDS


def test_prior_classes_are_the_schemas():
    """The schema's ``prior`` enum and default are the table's classes and default; absent reads as paper."""
    from forcdecode.core.parameters import DEFAULT_PRIOR_CLASS, PRIOR_CLASSES, k_u_floor, prior_class

    schema = yaml.safe_load(SCHEMA_PATH.read_text())["properties"]["prior"]
    assert tuple(schema["enum"]) == tuple(PRIOR_CLASSES) == ("paper", "perpendicular")
    assert schema["default"] == DEFAULT_PRIOR_CLASS == "paper"
    assert prior_class(None) == prior_class({}) == prior_class({"seed": 1}) == "paper"
    assert prior_class({"prior": "perpendicular"}) == prior_class({"prior_class": "perpendicular"}) == "perpendicular"
    with pytest.raises(ValueError, match="unknown prior class"):
        prior_class("inplane")
    assert k_u_floor(8e5) == 1e3  # paper: the bound
    assert k_u_floor(8e5, "perpendicular") == pytest.approx(4e-7 * math.pi * 8e5**2 / 2)
    with pytest.raises(ValueError, match="K_eff > 0"):
        k_u_floor(1.6e6, "perpendicular")
