"""twin.plant.linearize and ``twin linearize``: the linearised model agrees with the models the
designs use (ts_model's upright rule, lqr's yaw model), its operating points are steady motions
of the twin's equations, the voltage model is the torque model with the motor folded in, the
JSON keeps names, units and shapes and is the same bytes every time, and bad input is one line."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import control
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.linalg import expm

from twin.commands.linearize import linearize as linearize_command
from twin.controllers.lqr import yaw_model
from twin.errors import TwinError
from twin.plant import linearize as lin
from twin.plant.analytic import NO_TAU, rhs, rk4_step
from twin.plant.ts_model import local_model
from twin.robots import builtin_names, load_robot
from twin.robots.robot import ROBOT_KEYS

ROBOTS = ("paper", "balboa", "rmp220")
BALANCE, YAW = [0, 1, 2, 3], [4, 5]
STATE_NAMES = ["theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot"]
STATE_UNITS = ["rad", "rad/s", "rad", "rad/s", "rad", "rad/s"]


def close(a, b, rtol=1e-9):
    """Entrywise |a − b| ≤ rtol·|b|, with an absolute floor of rtol times the matrix's largest entry
    (entries that are 0 in one come out 0 or at rounding level in the other)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * max(1e-300, np.abs(b).max()))


def test_the_builtins_are_the_three_this_file_checks():
    assert sorted(builtin_names()) == sorted(ROBOTS)


@pytest.mark.parametrize("name", ROBOTS)
def test_upright_rest_agrees_with_the_ts_and_yaw_models(name):
    robot = load_robot(name)
    p = robot.params()
    sys_ = lin.linearize(robot)
    A, B = np.asarray(sys_.A), np.asarray(sys_.B)
    A1, B1 = local_model(p, 1.0)
    close(A[np.ix_(BALANCE, BALANCE)], A1)
    close(B[BALANCE, 0], B1[:, 0])  # u = ul + ur: each wheel's column is ∂/∂u
    close(B[BALANCE, 1], B1[:, 0])
    Ay, By = yaw_model(p)
    close(A[np.ix_(YAW, YAW)], Ay)
    close(B[YAW, 1] - B[YAW, 0], By[:, 0])  # ur − ul = 2 u_α
    # decoupled at rest: no yaw in the balance rows, no balance in the yaw rows
    assert np.all(A[np.ix_(BALANCE, YAW)] == 0.0) and np.all(A[np.ix_(YAW, BALANCE)] == 0.0)
    assert np.all(B[BALANCE, 1] - B[BALANCE, 0] == 0.0) and np.all(B[YAW, 0] + B[YAW, 1] == 0.0)
    # the kinematic rows are exact (power-of-two steps)
    for row, col in ((0, 1), (2, 3), (4, 5)):
        assert list(A[row]) == [1.0 if j == col else 0.0 for j in range(6)]


@pytest.mark.parametrize("name", ROBOTS)
def test_one_unstable_pole_real_and_positive_and_without_damping_the_formula(name):
    robot = load_robot(name)
    eig = np.linalg.eigvals(np.asarray(lin.linearize(robot).A))
    unstable = [e for e in eig if e.real > 1e-9]
    assert len(unstable) == 1 and unstable[0].imag == 0.0 and unstable[0].real > 0.0
    p = robot.params().replace(d_b=0.0, d_w=0.0)
    eig = np.linalg.eigvals(np.asarray(lin.linearize(p).A))
    expected = math.sqrt(p.m11 * p.g_b / (p.m11 * p.m22 - p.m12 * p.m12))
    top = max(eig, key=lambda e: e.real)
    assert top.imag == 0.0
    assert abs(top.real - expected) <= 1e-9 * expected
    # and its mirror: ±√(m11 g_b / Δ), the other four at the origin
    assert min(abs(e + expected) for e in eig) <= 1e-9 * expected
    assert sum(abs(e) <= 1e-9 * expected for e in eig) == 4


def test_model_names_units_and_shapes():
    sys_ = lin.linearize(load_robot("paper"))
    assert isinstance(sys_, control.StateSpace) and sys_.isctime()
    assert sys_.state_labels == STATE_NAMES and sys_.output_labels == STATE_NAMES
    assert sys_.input_labels == ["ul", "ur"]
    assert [sys_.units[n] for n in STATE_NAMES] == STATE_UNITS and sys_.units["ul"] == "N·m"
    assert np.asarray(sys_.A).shape == (6, 6) and np.asarray(sys_.B).shape == (6, 2)
    assert np.array_equal(sys_.C, np.eye(6)) and np.array_equal(sys_.D, np.zeros((6, 2)))
    volt = lin.linearize(load_robot("paper"), input="voltage")
    assert volt.input_labels == ["vl", "vr"] and volt.units["vl"] == "V"


def test_json_round_trip():
    sys_ = lin.linearize(load_robot("balboa"), at={"speed": 0.2, "yaw_rate": 0.5}, input="voltage", dt=0.01)
    d = json.loads(lin.to_json(lin.model_dict(sys_)))
    assert d["robot"] == "balboa" and d["input"] == "voltage" and d["time"] == "discrete" and d["dt"] == 0.01
    assert [s["name"] for s in d["states"]] == STATE_NAMES and [s["unit"] for s in d["states"]] == STATE_UNITS
    assert d["outputs"] == d["states"]
    assert [(i["name"], i["unit"]) for i in d["inputs"]] == [("vl", "V"), ("vr", "V")]
    for key, shape in (("A", (6, 6)), ("B", (6, 2)), ("C", (6, 6)), ("D", (6, 2))):
        m = np.array(d[key])
        assert m.shape == shape
        assert np.array_equal(m, np.asarray(getattr(sys_, key)))  # floats round-trip exactly
    assert np.array_equal(d["C"], np.eye(6)) and np.array_equal(d["D"], np.zeros((6, 2)))
    op = d["operating_point"]
    assert op["speed"] == 0.2 and op["yaw_rate"] == 0.5 and len(op["state"]) == 6
    assert op["state"][0] == op["theta"] > 0.0  # leaning into the rolling resistance
    assert len(d["eigenvalues"]) == 6 and all(len(e) == 2 for e in d["eigenvalues"])
    assert any("C is the identity and D is zero" in n for n in d["notes"])
    # the operating point written out is accepted back (theta with speed: the same steady motion)
    again = lin.operating_point(load_robot("balboa"), {k: op[k] for k in ("theta", "speed", "yaw_rate")})
    assert abs(again.theta - op["theta"]) <= 1e-12


def test_model_dict_refuses_a_system_it_did_not_make():
    with pytest.raises(TwinError, match="needs a model from twin.plant.linearize.linearize"):
        lin.model_dict(control.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]]))


@pytest.mark.parametrize("at", [None, {"speed": 0.25, "yaw_rate": -1.5}])
def test_voltage_input_is_the_torque_model_with_the_motor_folded_in(at):
    robot = load_robot("paper")
    p, m = robot.params(), robot.motor()
    torque = lin.linearize(robot, at=at)
    volt = lin.linearize(robot, at=at, input="voltage")
    At, Bt, Av, Bv = (np.asarray(M) for M in (torque.A, torque.B, volt.A, volt.B))
    close(Bv, Bt * (m.k_t / m.resistance))
    # τ_l,r = k_t (V − k_e ω_l,r)/R, ω_l,r = ψ̇ ∓ (b/r) α̇ − θ̇: ∂τ/∂x = −c ∂ω/∂x
    half = p.b / p.r
    dtau = -m.electrical_damping * np.array([[0.0, -1.0, 0.0, 1.0, 0.0, -half], [0.0, -1.0, 0.0, 1.0, 0.0, half]])
    close(Av, At + Bt @ dtau)
    # the same thing said physically: the back-EMF is damping c added to the drive's d_b
    damped = lin.linearize(p.replace(d_b=p.d_b + m.electrical_damping), at=at, motor=m)
    close(Av, np.asarray(damped.A))
    # and the voltages of the operating point give its torques
    op = volt.operating_point
    close(op.torque, [m.k_t * (v - m.k_t * w) / m.resistance
                      for v, w in zip(op.voltage, (op.state[3] - half * op.state[5], op.state[3] + half * op.state[5]))])


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("at", [{"speed": 0.3}, {"speed": -0.2, "yaw_rate": 1.0}, {"yaw_rate": 2.0}])
def test_operating_points_are_steady_motions_of_the_twins_equations(name, at):
    robot = load_robot(name)
    p = robot.params()
    op = lin.operating_point(robot, at)
    f = rhs(op.state, op.torque[0], op.torque[1], p, NO_TAU)
    assert max(abs(f[i]) for i in (1, 3, 5)) <= 1e-10 * (1.0 + p.g_b / p.m22)
    assert op.speed == at.get("speed", 0.0) and op.yaw_rate == at.get("yaw_rate", 0.0)
    # the tilt leans into the rolling resistance, and gives the speed back
    assert math.copysign(1.0, op.theta) == math.copysign(1.0, op.speed) or op.speed == 0.0
    if op.speed != 0.0:
        back = lin.operating_point(robot, {"theta": op.theta, "yaw_rate": op.yaw_rate})
        assert abs(back.speed - op.speed) <= 1e-9 * abs(op.speed)


def test_the_model_at_a_moving_point_predicts_the_nonlinear_motion():
    """A small deviation from a steady turn, integrated by the twin's RK4, follows exp(A t)."""
    robot = load_robot("paper")
    p = robot.params()
    sys_ = lin.linearize(robot, at="speed=0.5,yaw_rate=1")
    op = sys_.operating_point
    x0 = np.array([*op.state, 0.0, 0.0])
    dx = np.array([2e-6, -1e-6, 0.0, 3e-6, 0.0, -2e-6])
    x, ref = x0 + np.r_[dx, 0.0, 0.0], x0.copy()
    h, n = 1e-4, 500
    for _ in range(n):
        x = rk4_step(x, op.torque[0], op.torque[1], p, h)
        ref = rk4_step(ref, op.torque[0], op.torque[1], p, h)
    predicted = expm(np.asarray(sys_.A) * h * n) @ dx
    close((x - ref)[:6], predicted, rtol=1e-4)


def test_discrete_model_is_the_zero_order_hold():
    robot = load_robot("rmp220")
    c = lin.linearize(robot)
    d = lin.linearize(robot, dt=0.005)
    assert d.isdtime() and d.dt == 0.005 and d.state_labels == STATE_NAMES and d.input_labels == ["ul", "ur"]
    M = expm(np.block([[np.asarray(c.A), np.asarray(c.B)], [np.zeros((2, 8))]]) * 0.005)
    close(d.A, M[:6, :6], rtol=1e-10)
    close(d.B, M[:6, 6:], rtol=1e-10)
    assert d.units == c.units and d.operating_point == c.operating_point


def _cli(args):
    return CliRunner().invoke(linearize_command, args, catch_exceptions=True)


def test_command_prints_the_json_the_function_gives_and_writes_it_with_out(tmp_path):
    r = _cli(["--robot", "balboa", "--at", "speed=0.2", "--input", "voltage", "--dt", "0.01"])
    assert r.exit_code == 0, r.output
    model = lin.linearize(load_robot("balboa"), at={"speed": 0.2}, input="voltage", dt=0.01)
    assert r.output == lin.to_json(lin.model_dict(model))
    out = tmp_path / "sub" / "model.json"
    w = _cli(["--robot", "balboa", "--at", "speed=0.2", "--input", "voltage", "--dt", "0.01", "--out", str(out)])
    assert w.exit_code == 0 and w.output == f"wrote {out}\n"
    assert out.read_text(encoding="utf-8") == r.output


def test_same_bytes_twice_and_in_another_process():
    args = ["--robot", "paper", "--at", "speed=0.5,yaw_rate=1", "--input", "voltage"]
    first, second = _cli(args).output, _cli(args).output
    assert first == second and first.startswith("{")
    code = ("import sys; from twin.commands.linearize import linearize\n"
            f"linearize.main({args!r}, standalone_mode=False)\n")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert other.returncode == 0, other.stderr
    assert other.stdout == first


@pytest.mark.parametrize("args, says", [
    (["--robot", "nope"], "no robot 'nope': neither a built-in (balboa, paper, rmp220) nor a .toml file"),
    (["--at", "speed"], "--at must be KEY=VALUE pairs separated by commas with keys theta (rad), speed (m/s), "
                        "yaw_rate (rad/s)"),
    (["--at", "speed=1,speed=2"], "--at names speed twice; allowed: each key once"),
    (["--at", "tilt=0.1"], "--at: unknown key 'tilt'; allowed: theta (rad), speed (m/s), yaw_rate (rad/s)"),
    (["--at", "speed=fast"], "--at speed: must be a finite number in m/s, got 'fast'"),
    (["--at", "yaw_rate=nan"], "--at yaw_rate: must be a finite number in rad/s"),
    (["--at", "theta=1.1"], "theta is past the robot's fall angle; allowed: |theta| < 1 rad"),
    (["--at", "theta=0.1,speed=0.1"], "the tilt is not steady at this speed (it would accelerate); allowed: "
                                      "theta=0.03176"),
    (["--at", "speed=5"], "no steady motion: the lean that balances the rolling resistance passes the fall angle "
                          "1 rad; allowed: |speed| ≤ 1.06 m/s at yaw_rate=0 rad/s"),
    (["--at", "speed=1.2"], "both motors need 13.59 V, above the 12 V supply; allowed: |speed| ≤ 1.06 m/s"),
    (["--at", "yaw_rate=50"], "above the 12 V supply; allowed: |yaw_rate| ≤ 7.066 rad/s (at rest)"),
    (["--dt", "0"], "--dt must be a sampling period in (0, 1] s, got 0"),
    (["--dt", "-0.01"], "--dt must be a sampling period in (0, 1] s, got -0.01"),
    (["--dt", "2"], "--dt must be a sampling period in (0, 1] s, got 2"),
])
def test_bad_input_is_one_twin_error_line(args, says):
    r = _cli(args)
    assert isinstance(r.exception, TwinError), (r.output, r.exception)
    message = str(r.exception)
    assert "\n" not in message and says in message, message
    assert r.output == ""


def test_a_tilt_is_refused_where_nothing_holds_it():
    p = load_robot("paper").params().replace(d_w=0.0)
    with pytest.raises(TwinError, match=r"a constant tilt is no steady state of this robot .*allowed: theta=0"):
        lin.operating_point(p, {"theta": 0.1})
    assert lin.operating_point(p, {"speed": 1.0}).theta == 0.0  # without rolling resistance: upright at any speed


def test_python_api_refuses_bad_arguments_in_one_line():
    robot = load_robot("paper")
    for kwargs, says in (({"input": "current"}, "input must be one of torque, voltage"),
                         ({"dt": 0.0}, "dt must be a sampling period in (0, 1] s"),
                         ({"at": {"speed": "1"}}, "operating point speed: must be a finite number in m/s"),
                         ({"at": {"v": 1.0}}, "operating point: unknown key 'v'")):
        with pytest.raises(TwinError, match="^" + __import__("re").escape(says)):
            lin.linearize(robot, **kwargs)
    with pytest.raises(TwinError, match="linearize needs a robot"):
        lin.linearize("paper")


def test_a_bare_parameter_set_falls_at_the_robot_files_default_angle():
    assert lin.DEFAULT_FALL_ANGLE == ROBOT_KEYS["limits"]["fall_angle"].default


@pytest.mark.skipif("linearize" not in __import__("twin.cli").cli.COMMANDS,
                    reason="twin linearize is not registered in twin/cli.py's COMMANDS yet")
def test_the_real_command_line_says_one_line_and_exits_2():
    from twin.cli import main

    ok = CliRunner().invoke(main, ["linearize", "--robot", "rmp220"])
    assert ok.exit_code == 0 and json.loads(ok.output)["robot"] == "rmp220"
    for args in (["--at", "speed=oops"], ["--dt", "0"], ["--robot", "nope"], ["--at", "speed=50"]):
        r = CliRunner().invoke(main, ["linearize", *args])
        assert r.exit_code == 2, (args, r.output)
        lines = r.output.strip().splitlines()  # click's runner mixes stderr into output
        assert len(lines) == 1 and lines[0].startswith("error: "), (args, r.output)
