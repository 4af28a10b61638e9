"""The hobby robot's recordings of the robot-logs how-to: what a balancing robot's own firmware
logs over its serial port, made by the independent simulator (:mod:`foreign.robot_sim`,
profile B) and written as such a firmware writes it — raw sensor codes in the chip's own axes,
motor encoder counts with one wheel counting backwards, PWM values, milliseconds.

Nothing here comes from ``twin`` or ``estimation``. The simulator's readings are already the
sensors' 16-bit codes (an MPU-6050 at ±500 °/s and ±2 g) and its commands 8-bit PWM steps of a
12 V supply, so the raw values written are exact integers. What the robot is and how it was
built (the "ground truth" a real robot's owner would not have) is in
:func:`recording_facts`; the how-to never reads it, the tests do.

One CSV per recording, the header first::

    ms,ax,ay,az,gx,gy,gz,enc_l,enc_r,pwm_l,pwm_r

* ``ms``: the firmware's millisecond clock at the row (rows every 30–33 ms, the logger
  decimating a 1 kHz loop); the first row at 0.
* ``ax, ay, az``: the accelerometer's codes, 16384 per g (g = 9.80665 m/s²); ``gx, gy, gz``:
  the gyro's, 65.536 per °/s. The chip's axes: X towards the right wheel, Y forward, Z up,
  the board then pitched forward by 0.07 rad about the axle (a tilted mount).
* ``enc_l, enc_r``: each motor's encoder, 48 counts per motor revolution (12 lines,
  quadrature ×4), a 30:1 gearbox, counted from power-up; the right motor is mounted mirrored,
  so its count goes *down* when the wheel rolls forward.
* ``pwm_l, pwm_r``: the drivers' PWM values, −255…255 (forward positive, both), of a 12 V
  supply, as the 1 kHz loop had set them at the row's instant (sampled, not held).

``python -m foreign.hobby_recording DIR`` (from ``tests/``) writes the how-to's two recordings
into DIR; tests/test_hobby_recording.py checks that the copies under docs/ are these.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from foreign.robot_sim import DEG, G0, profile_b, simulate

HEADER = ("ms", "ax", "ay", "az", "gx", "gy", "gz", "enc_l", "enc_r", "pwm_l", "pwm_r")
RECORDINGS = {"balance-1.csv": 3, "balance-2.csv": 4}  # file name: the simulator's seed
GYRO_LSB = 32768.0 / 500.0  # codes per °/s (±500 °/s)
ACCEL_LSB = 32768.0 / 2.0  # codes per g (±2 g)
PWM_MAX = 255
COUNTS_PER_MOTOR_REV, GEAR = 48, 30


def _chip(v) -> tuple[float, float, float]:
    """The simulator's IMU axes (x forward, y left, z up, pitched with the board) in the chip's:
    X right, Y forward, Z up."""
    x, y, z = v
    return -y, x, z


def rows(seed: int) -> list[tuple[int, ...]]:
    """The recording of the simulator's profile-B robot run with ``seed``: one tuple of ints per row."""
    spec = profile_b(seed=seed)
    if spec.imu.gyro_range != 500.0 * DEG or spec.imu.accel_range != 2.0 * G0 or spec.imu.bits != 16:
        raise ValueError("the hobby recording expects the simulator's ±500 °/s, ±2 g, 16-bit IMU")
    if spec.encoder_counts != COUNTS_PER_MOTOR_REV * GEAR:
        raise ValueError("the hobby recording expects 1440 counts per wheel revolution")
    res = simulate(spec)
    supply = spec.motor.supply
    out = []
    for (t, g, a), (te, el, er), (tc, ul, ur) in zip(res.imu_rows, res.encoder_rows, res.command_rows):
        if not (t == te == tc):
            raise ValueError(f"the simulator's streams are not row-aligned at t = {t}")
        gc = [v / (1.0 * DEG) * GYRO_LSB for v in _chip(g)]
        ac = [v / G0 * ACCEL_LSB for v in _chip(a)]
        pw = [u / supply * PWM_MAX for u in (ul, ur)]
        vals = [*ac, *gc, *pw]
        ints = [int(round(v)) for v in vals]
        if max(abs(v - i) for v, i in zip(vals, ints)) > 1e-6:
            raise ValueError(f"a reading at t = {t} is not a whole code")
        ms = t * 1000.0
        if abs(ms - round(ms)) > 1e-6:
            raise ValueError(f"a row at t = {t} s is not on the millisecond clock")
        out.append((int(round(ms)), *ints[:6], int(el), -int(er), *ints[6:]))
    return out


def write(path, seed: int) -> Path:
    path = Path(path)
    lines = [",".join(HEADER)] + [",".join(str(v) for v in r) for r in rows(seed)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def recording_facts(seed: int) -> dict:
    """What the tests compare the how-to's results with: the simulator's true plant and motors, the
    board's mounting pitch (rad), the true noise per row (σ of the vibration and white noise)."""
    spec = profile_b(seed=seed)
    p, m = spec.plant, spec.motor
    return {"plant": {k: getattr(p, k) for k in ("m_w", "m_b", "n_wa", "n_wd", "n_yb", "n_zb", "l", "d_b", "d_w",
                                                 "r", "b")},
            "motor": {"supply_voltage": m.supply, "stall_torque": m.stall_torque, "no_load_speed": m.no_load_speed},
            "mount_pitch": spec.imu.mount_pitch, "theta0": spec.initial[0], "duration": spec.duration,
            "vibration": {"gyro": spec.imu.vibration_gyro, "accel": spec.imu.vibration_accel},
            "counts_per_wheel_rev": spec.encoder_counts, "wheel_radius_m": p.r, "track_m": 2.0 * p.b,
            "gyro_lsb_per_dps": GYRO_LSB, "accel_lsb_per_g": ACCEL_LSB, "right_encoder_sign": -1,
            "chip_axes": "X right, Y forward, Z up"}


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description="Write the robot-logs how-to's hobby recordings.")
    ap.add_argument("out")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, seed in RECORDINGS.items():
        write(out / name, seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
