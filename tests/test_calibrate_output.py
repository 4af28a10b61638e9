"""calibration.toml for a robot the twin cannot run (other wheels or track, or a parameter outside plant.scale's range of
Table III): the calibration is kept and says so, and 'twin run --plant' refuses it in one line."""
from __future__ import annotations

import tomllib
from types import SimpleNamespace

import pytest

from twin.calibrate import output
from twin.errors import TwinError
from twin.params import NOMINAL


def _params(n_zb_factor: float) -> dict:
    e = {"identifiable": True, "unit": "kg·m²"}
    return {"m_b": dict(e, value=NOMINAL.m_b * 0.9, unit="kg"),
            "n_zb": dict(e, value=NOMINAL.n_zb * n_zb_factor)}


def test_a_robot_inside_the_range_gets_its_plant_scale(tmp_path):
    text = output.calibration_toml(SimpleNamespace(logs=["a"]), _params(1.5))
    doc = tomllib.loads(text)
    assert doc["plant"]["scale"]["n_zb"] == pytest.approx(1.5) and "twin_runnable" not in doc["calibration"]
    (tmp_path / "c.toml").write_text(text, encoding="utf-8")
    assert any(i.startswith("plant.scale=") for i in output.plant_overrides(tmp_path / "c.toml"))


def test_a_robot_outside_the_range_is_kept_and_refused_in_one_line(tmp_path):
    text = output.calibration_toml(SimpleNamespace(logs=["a"]), _params(5.78))
    doc = tomllib.loads(text)
    assert "plant" not in doc and doc["calibration"]["twin_runnable"] is False
    assert "n_zb" in doc["calibration"]["twin_why"] and "5.78" in doc["calibration"]["twin_why"]
    (tmp_path / "c.toml").write_text(text, encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        output.plant_overrides(tmp_path / "c.toml")
    msg = str(exc.value)
    assert "\n" not in msg and "cannot run this calibrated robot" in msg and "n_zb" in msg


def test_a_robot_with_other_wheels_or_track_is_not_given_to_the_twin():
    same = tomllib.loads(output.calibration_toml(SimpleNamespace(logs=["a"]), _params(1.5),
                                                 geometry=(NOMINAL.r, NOMINAL.b)))
    assert "plant" in same and "twin_runnable" not in same["calibration"]
    other = tomllib.loads(output.calibration_toml(SimpleNamespace(logs=["a"]), _params(1.5), geometry=(0.03, 0.08)))
    assert "plant" not in other and other["calibration"]["twin_runnable"] is False
    assert "wheel radius 0.03 m and track 0.16 m" in other["calibration"]["twin_why"]
