"""The registry of what ``twin calibrate`` can fit (issue 30, in progress)."""
from __future__ import annotations

import dataclasses

import pytest

from twin.actuators.dc_motor import DCMotorParams
from twin.calibrate.parameters import DEFAULT_PLANT, PARAMETERS, parse_names
from twin.errors import TwinError
from twin.params import PARAMETER_DOCS


def test_every_plant_and_motor_parameter_names_a_field_of_its_model():
    motor_fields = {f.name for f in dataclasses.fields(DCMotorParams)}
    for p in PARAMETERS.values():
        assert p.group in ("plant", "motor", "imu", "current") and p.unit and p.doc
        if p.group == "plant":
            assert p.name in PARAMETER_DOCS and PARAMETER_DOCS[p.name][0] == p.unit, p
        if p.group == "motor":
            assert p.name in motor_fields, p
    assert set(DEFAULT_PLANT) <= set(PARAMETERS) and "n_zb" not in DEFAULT_PLANT


def test_names_are_parsed_in_registry_order():
    assert parse_names("n_yb, m_b,l") == ("m_b", "l", "n_yb")
    assert parse_names("gyro_bias_y") == ("gyro_bias_y",)


@pytest.mark.parametrize("text, says", [
    ("", "needs at least one name"),
    ("m_b,,l", "empty name"),
    ("m_b,mass", "no parameter 'mass'; allowed: m_b, l,"),
    ("l,l", "more than once"),
])
def test_bad_names_give_one_line_naming_what_is_allowed(text, says):
    with pytest.raises(TwinError) as err:
        parse_names(text)
    msg = str(err.value)
    assert says in msg and "\n" not in msg
