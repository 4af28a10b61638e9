"""The applied PWM duty in sensor logs (issue 30's prerequisite): the optional duty.csv holds the
duty the motor drivers applied (after the current limit, back-EMF compensation, the dead band
and the PWM rounding), the twin writes it for runs with DC motors and reads it back bit for bit;
a log without it reads with ``duty`` None; a malformed duty.csv is one line naming the file and
the row. And a log whose commands are a PWM duty replays without the back-EMF compensation
counted twice (the duty is past the driver)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from test_sensor_logs import _twin, write_by_hand
from twin.errors import TwinError
from twin.logs.format import STREAMS, SensorLog, read_log, write_log
from twin.logs.replay import build_for, errors, replay
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario


@pytest.fixture(scope="module")
def twin_log(tmp_path_factory):
    """A 3 s paper-exp3 run of LQR with DC motors (the default), its log directory."""
    sc = load_scenario("paper-exp3", ["duration=3"])
    run = run_scenario(sc, ["lqr"]).runs[0]
    d = write_log(run, tmp_path_factory.mktemp("duty") / "lqr", sc)
    return run, d


def test_the_twins_log_carries_the_applied_duty_bit_for_bit(twin_log):
    run, d = twin_log
    assert (d / "duty.csv").read_text().splitlines()[0] == "t,duty_l,duty_r" == ",".join(STREAMS["duty"])
    log = read_log(d)
    applied = np.column_stack([run.signal("duty_l"), run.signal("duty_r")])
    assert log.duty.shape == applied.shape == (len(run.t), 2)
    assert log.duty.tobytes() == applied.tobytes()
    assert log.duty_t.tobytes() == run.t.tobytes() == log.commands_t.tobytes()  # one row per control period
    # the duty the drivers applied, not the command over the stall torque: the compensation and
    # the 10-bit rounding are in it
    steps = log.motor.pwm_steps
    assert np.array_equal(np.round(log.duty * steps), log.duty * steps)
    assert not np.allclose(log.duty, log.commands / log.motor.stall_torque, atol=1e-3)
    assert np.abs(log.duty).max() <= 1.0 and np.abs(log.duty).max() > 0.1


def test_ideal_torque_sources_and_older_logs_have_no_duty(tmp_path):
    log = read_log(write_by_hand(tmp_path / "hand", seconds=0.5))  # a log of before duty.csv
    assert log.duty is None and log.duty_t is None
    sc = load_scenario("paper-exp2", ["duration=0.5", 'plant.motor="ideal"'])
    run = run_scenario(sc, ["lqr"]).runs[0]
    d = tmp_path / "ideal"
    d.mkdir()
    (d / "duty.csv").write_text("t,duty_l,duty_r\n0.0,0.5,0.5\n")  # a stale one: not this run's
    write_log(run, d, sc)
    assert not (d / "duty.csv").exists()
    log = read_log(d)
    assert log.duty is None and log.duty_t is None


def test_a_subset_of_the_control_instants_may_carry_a_duty(twin_log, tmp_path):
    _, src = twin_log
    d = tmp_path / "subset"
    shutil.copytree(src, d)
    lines = (d / "duty.csv").read_text().splitlines()
    kept = [lines[0]] + lines[1::3]
    (d / "duty.csv").write_text("\n".join(kept) + "\n")
    log = read_log(d)
    assert len(log.duty_t) == len(kept) - 1 and np.array_equal(log.duty_t, log.commands_t[::3])


def _edit(d: Path, row: int, text: str | None = None, header: str | None = None) -> None:
    lines = (d / "duty.csv").read_text().splitlines()
    if header is not None:
        lines[0] = header
    if text is not None:
        lines[row - 1] = text
    (d / "duty.csv").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("how, fragment", [
    ("header", r"duty.csv: row 1: the header must be t,duty_l,duty_r, got 't,ul,ur'"),
    ("nan", r"duty.csv: row 4: duty_l = nan; allowed: a finite number"),
    ("inf", r"duty.csv: row 4: duty_r = inf; allowed: a finite number"),
    ("range", r"duty.csv: row 4: duty_r = -1.25 is outside \[-1, 1\]"),
    ("empty", r"duty.csv: row 4: duty_r is empty; every row needs duty_l and duty_r"),
    ("text", r"duty.csv: row 4: duty_l = 'half' is not a number"),
    ("misaligned", r"duty.csv: row 4: t = 0.0125 s is no control instant of commands.csv"),
    ("duplicate", r"duty.csv: row 4: t = 0.005 s repeats the row before's instant"),
    ("backwards", r"duty.csv: row 4: t = 0.0 s runs backwards"),
])
def test_a_bad_duty_csv_is_one_line_naming_the_file_and_row(twin_log, tmp_path, how, fragment):
    _, src = twin_log
    d = tmp_path / how
    shutil.copytree(src, d)
    t = (d / "duty.csv").read_text().splitlines()[3].split(",")[0]  # row 4's time: 0.01 s
    assert float(t) == 0.01
    edits = {"header": dict(header="t,ul,ur"), "nan": dict(text=f"{t},nan,0.5"), "inf": dict(text=f"{t},0.5,inf"),
             "range": dict(text=f"{t},0.5,-1.25"), "empty": dict(text=f"{t},0.5,"),
             "text": dict(text=f"{t},half,0.5"), "misaligned": dict(text="0.0125,0.5,0.5"),
             "duplicate": dict(text="0.005,0.5,0.5"), "backwards": dict(text="0.0,0.5,0.5")}
    _edit(d, 4, **edits[how])
    with pytest.raises(TwinError, match=fragment) as exc:
        read_log(d)
    assert "\n" not in str(exc.value)


def test_a_bad_duty_csv_is_one_line_and_exit_status_2_on_the_command_line(twin_log, tmp_path):
    _, src = twin_log
    d = tmp_path / "cli"
    shutil.copytree(src, d)
    _edit(d, 3, text="0.01,1.5,0.0")
    status, stdout, stderr = _twin("replay", str(d), "--estimator", "ekf", "--out", str(tmp_path / "o"))
    assert status == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "duty.csv: row 3: duty_l = 1.5 is outside [-1, 1]" in lines[0], stderr


def _as_duty_commands(src: Path, d: Path) -> Path:
    """The twin's log with commands.csv holding the applied duty, [commands] unit = "duty"."""
    shutil.copytree(src, d)
    toml = (d / "log.toml").read_text()
    assert '[commands]\nunit = "N·m"' in toml
    (d / "log.toml").write_text(toml.replace('[commands]\nunit = "N·m"', '[commands]\nunit = "duty"'))
    (d / "commands.csv").write_text((d / "duty.csv").read_text().replace("t,duty_l,duty_r", "t,ul,ur", 1))
    return d


def test_duty_commands_are_past_the_driver_so_the_ekf_does_not_compensate_twice(twin_log, tmp_path,
                                                                                monkeypatch):
    """commands.unit = "duty": duty × stall torque is the held torque τ_0, the driver's back-EMF
    compensation already in it. The EKF's model (estimation.model.EstimatorModel.delivered) adds
    c_e ω to an N·m command; it must not add it to τ_0 again."""
    from estimation.model import EstimatorModel

    run, src = twin_log
    log = read_log(_as_duty_commands(src, tmp_path / "duty"))
    assert log.motor.back_emf_compensation  # the default driver compensates
    assert np.array_equal(log.commands, log.duty * log.motor.stall_torque)
    x = np.zeros(12)
    x[1], x[3], x[5] = -1.0, 5.0, 0.5  # θ̇, ψ̇, α̇: the wheels turn relative to the body
    fixed = EstimatorModel(log.model, log.context().motor, log.sensors.imu, log.sensors.encoders, log.control_rate)
    as_is = EstimatorModel(log.model, log.motor, log.sensors.imu, log.sensors.encoders, log.control_rate)
    for ul, ur in log.commands[::50]:
        assert fixed.delivered(x, ul, ur) == (ul, ur)  # τ_0 handed through
        assert as_is.delivered(x, ul, ur) != (ul, ur)  # what the bug did: c_e ω added a second time
    assert fixed.c_e == as_is.c_e > 0  # the back-EMF slope still damps the wheels in the model

    # replayed, the EKF on the duty log is as good as on the twin's own N·m log; with the motor as
    # the log gives it (compensating), it was several times worse
    nm = read_log(src)
    e_nm = errors(nm, replay(nm, build_for(nm, "ekf"), "ekf"))
    e_fixed = errors(log, replay(log, build_for(log, "ekf"), "ekf"))
    assert e_fixed["theta_rmse_rad"] < 1.2 * e_nm["theta_rmse_rad"]
    assert e_fixed["psi_rmse_rad"] < 1.2 * e_nm["psi_rmse_rad"]
    monkeypatch.setattr(SensorLog, "estimator_motor", lambda self: self.motor)
    e_twice = errors(log, replay(log, build_for(log, "ekf"), "ekf"))
    assert e_twice["theta_rmse_rad"] > 2.0 * e_fixed["theta_rmse_rad"]
    assert e_twice["psi_rmse_rad"] > 2.0 * e_fixed["psi_rmse_rad"]


def test_n_m_commands_keep_the_motor_as_it_is(twin_log):
    _, src = twin_log
    log = read_log(src)
    assert log.context().motor is log.motor  # the controller's N·m: the EKF's model is the driver
