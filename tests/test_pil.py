"""Processor in the loop, emulated (twin/export/pil.py): a stand-in export (a complementary filter
and a linear state feedback, float32, written here) cross-compiled for a Cortex-M4F, run under
QEMU and on the host, the two duty streams compared, its flash, RAM and instructions per step
held to a small part's budget.

Needs arm-none-eabi-gcc with newlib and qemu-system-arm (Debian: gcc-arm-none-eabi,
libnewlib-arm-none-eabi, qemu-system-arm); skips without them unless TWIN_REQUIRE_PIL=1.
"""
import json
import os
import shutil

import numpy as np
import pytest

from twin.errors import TwinError
from twin.export import pil

_MISSING = [t for t in ("arm-none-eabi-gcc", "qemu-system-arm") if shutil.which(t) is None]
needs_tools = pytest.mark.skipif(bool(_MISSING) and os.environ.get("TWIN_REQUIRE_PIL") != "1",
                                 reason=f"{' and '.join(_MISSING)} not installed (Debian: {pil.DEBIAN_PACKAGES})")

STEPS = 600
PERIOD_INSTRUCTIONS = 0.005 * pil.CLOCK_HZ  # 5 ms at 168 MHz

PARAMS = """#ifndef MTWIP_PARAMS_H
#define MTWIP_PARAMS_H
#include <math.h>
typedef float mtwip_real;
#define MTWIP_R(x) ((mtwip_real)(x))
#define MTWIP_FLOAT32 1
%s
#define MTWIP_SQRT sqrtf
#define MTWIP_FABS fabsf
#define MTWIP_CONTROL_RATE_HZ 0x1.9p+7f
#include "mtwip_estimator.h"
#endif
"""
WITH_LIBM = "#define MTWIP_SIN sinf\n#define MTWIP_ATAN2 atan2f"
ARITHMETIC_ONLY = ("#define MTWIP_SIN(x) ((x) - (x) * (x) * (x) / MTWIP_R(6.0))\n"
                   "#define MTWIP_ATAN2(y, x) ((y) / (x))")

ESTIMATOR_H = """#ifndef MTWIP_ESTIMATOR_H
#define MTWIP_ESTIMATOR_H
typedef struct { mtwip_real x[6]; mtwip_real bias; } mtwip_estimator_t;
#endif
"""

ESTIMATOR_C = r"""#include <string.h>
#include "mtwip.h"
#define DT (MTWIP_R(1.0) / MTWIP_CONTROL_RATE_HZ)
static mtwip_real tilt(const mtwip_sample_t *s) { return MTWIP_ATAN2(s->accel[0], s->accel[2]); }
void mtwip_estimator_init(mtwip_estimator_t *e) { memset(e, 0, sizeof *e); }
void mtwip_estimator_start(mtwip_estimator_t *e, const mtwip_sample_t *s, mtwip_real estimate[6]) {
    e->x[0] = s->has_accel ? tilt(s) : MTWIP_R(0.0);
    memcpy(estimate, e->x, sizeof e->x);
}
void mtwip_estimator_step(mtwip_estimator_t *e, const mtwip_sample_t *s, const mtwip_real command[2],
                          mtwip_real estimate[6]) {
    (void)command;
    if (s->has_gyro) { e->x[1] = s->gyro[1] - e->bias; e->x[5] = s->gyro[2]; }
    e->x[0] += e->x[1] * DT;
    if (s->has_accel) {
        mtwip_real g = MTWIP_SQRT(s->accel[0] * s->accel[0] + s->accel[2] * s->accel[2]);
        if (MTWIP_FABS(g - MTWIP_R(9.81)) < MTWIP_R(2.0)) e->x[0] += MTWIP_R(0.02) * (tilt(s) - e->x[0]);
    }
    e->x[4] += e->x[5] * DT;
    if (s->has_encoder) {
        mtwip_real mean = MTWIP_R(0.5) * (s->encoder[0] + s->encoder[1]) + e->x[0];
        e->x[3] = (mean - e->x[2]) / DT;
        e->x[2] = mean;
    }
    memcpy(estimate, e->x, sizeof e->x);
}
"""

CONTROL_C = r"""#include "mtwip.h"
static const mtwip_real K[6] = {MTWIP_R(-2.5), MTWIP_R(-0.4), MTWIP_R(-0.05), MTWIP_R(-0.1), MTWIP_R(0.2),
                                MTWIP_R(0.03)};
void mtwip_control(const mtwip_real x[6], const mtwip_targets_t *t, mtwip_real out[5]) {
    mtwip_real off = t->has_position ? MTWIP_R(0.05) * (t->position - MTWIP_R(0.1) * x[2]) : MTWIP_R(0.0);
    mtwip_real u = -(K[0] * (x[0] - off) + K[1] * x[1] + K[2] * x[2] + K[3] * x[3]);
    mtwip_real ua = t->has_heading ? -(K[4] * MTWIP_SIN(x[4] - t->heading) + K[5] * x[5]) : MTWIP_R(0.0);
    out[0] = MTWIP_R(0.5) * u + ua;
    out[1] = MTWIP_R(0.5) * u - ua;
    out[2] = u; out[3] = off; out[4] = ua;
}
uint8_t mtwip_motor_duty(mtwip_real torque, mtwip_real omega, mtwip_real *duty) {
    mtwip_real d = (torque * MTWIP_R(2.0) + MTWIP_R(0.3) * omega) / MTWIP_R(7.4);
    if (d > MTWIP_R(1.0)) { *duty = MTWIP_R(1.0); return 1; }
    if (d < MTWIP_R(-1.0)) { *duty = MTWIP_R(-1.0); return 1; }
    *duty = d;
    return 0;
}
"""

MTWIP_C = r"""#include <string.h>
#include "mtwip.h"
void mtwip_default_config(mtwip_config_t *c) {
    c->gyro_scale = MTWIP_R(1.0); c->accel_scale = MTWIP_R(1.0); c->encoder_rad_per_count = MTWIP_R(0.001);
}
void mtwip_init(mtwip_state_t *s, const mtwip_config_t *c) {
    memset(s, 0, sizeof *s);
    s->config = *c;
    mtwip_estimator_init(&s->estimator);
}
void mtwip_step(mtwip_state_t *s, const mtwip_readings_t *r, const mtwip_targets_t *t, mtwip_outputs_t *o) {
    mtwip_sample_t m; mtwip_real c[5]; int i;
    for (i = 0; i < 3; i++) {
        m.gyro[i] = r->gyro[i] * s->config.gyro_scale;
        m.accel[i] = r->accel[i] * s->config.accel_scale;
    }
    for (i = 0; i < 2; i++) m.encoder[i] = (mtwip_real)r->encoder[i] * s->config.encoder_rad_per_count;
    m.has_gyro = r->gyro_valid; m.has_accel = r->accel_valid; m.has_encoder = r->encoder_valid;
    if (s->k == 0) mtwip_estimator_start(&s->estimator, &m, o->estimate);
    else mtwip_estimator_step(&s->estimator, &m, s->command, o->estimate);
    mtwip_control(o->estimate, t, c);
    for (i = 0; i < 2; i++) {
        o->torque[i] = c[i];
        o->saturated[i] = mtwip_motor_duty(c[i], o->estimate[3] - o->estimate[1], &o->duty[i]);
        s->command[i] = c[i];
    }
    o->u = c[2]; o->theta_off = c[3]; o->u_alpha = c[4];
    s->k++;
}
"""


def write_stand_in(directory, math=WITH_LIBM):
    directory.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(pil.PIL_SOURCES.parent / "mtwip.h", directory / "mtwip.h")
    files = {"mtwip_params.h": PARAMS % math, "mtwip_estimator.h": ESTIMATOR_H, "mtwip_estimator.c": ESTIMATOR_C,
             "mtwip_control.c": CONTROL_C, "mtwip.c": MTWIP_C,
             "test/test_host.c": "#error not library code: the build must leave test/ out\n"}
    for name, text in files.items():
        (directory / name).parent.mkdir(exist_ok=True)
        (directory / name).write_text(text)
    return directory


def synthetic_readings(n=STEPS, seed=3):
    """A robot rocking about upright: noisy gyros and accelerometers, the accelerometer at half
    the rate, encoders with a dropout and a slip now and then, the targets switched on and off."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    theta = 0.05 * np.sin(2 * np.pi * k / 150)
    r = pil.readings(n)
    r["gyro"][:, 1] = np.gradient(theta, 1 / 200) + rng.normal(0, 0.02, n)
    r["gyro"][:, 0] = rng.normal(0, 0.02, n)
    r["gyro"][:, 2] = 0.3 * np.sin(2 * np.pi * k / 400) + rng.normal(0, 0.02, n)
    r["accel"][:, 0] = 9.81 * np.sin(theta) + rng.normal(0, 0.3, n)
    r["accel"][:, 2] = 9.81 * np.cos(theta) + rng.normal(0, 0.3, n)
    steps = rng.integers(-3, 4, (n, 2)) + np.where(rng.random((n, 1)) < 0.02, 400, 0)
    r["encoder"] = np.cumsum(steps, axis=0)
    r["gyro_valid"] = 1
    r["accel_valid"] = k % 2 == 0
    r["encoder_valid"] = rng.random(n) > 0.05
    r["has_position"], r["position"] = k > 100, 0.4
    r["has_heading"], r["heading"] = k > 250, 0.3
    return r


@pytest.fixture(scope="module")
def stand_in(tmp_path_factory):
    """The stand-in (float32, with libm's sinf and atan2f) built for the target and the host, run on both."""
    root = tmp_path_factory.mktemp("pil")
    directory = write_stand_in(root / "export")
    readings = pil.write_readings(root / "readings.bin", synthetic_readings())
    info = pil.build(directory, root / "build")
    target = pil.run(info["image"], readings, timeout=20)
    host = pil.run_host(pil.build_host(directory, root / "build"), readings, timeout=20)
    return {"root": root, "dir": directory, "readings": readings, "info": info, "target": target, "host": host}


@needs_tools
def test_the_stand_in_fits_a_small_cortex_m4(stand_in):
    info = stand_in["info"]
    assert info["precision"] == "float32" and info["board"] == "netduinoplus2"
    assert 0 < info["library_flash"] <= info["image_flash"] <= 64 * 1024
    assert info["library_ram"] == 0  # no mutable global state (mtwip.h)
    # mtwip_state_t: the config (3 scales, the IMU's 3 × 3 turn), imu_turned (padded to 4 bytes), the stand-in's
    # estimator (7), the command (2), k
    assert info["state_bytes"] == stand_in["target"].info["state_bytes"] == 4 * (3 + 9) + 4 + 4 * (7 + 2) + 4
    assert info["stack_exact"], info["stack_notes"]
    assert [f[0] for f in info["stack_path"][:1]] == ["mtwip_step"] and info["stack_path"][0][2] == "su"
    assert info["stack_bytes"] == sum(f[1] for f in info["stack_path"])
    assert info["ram_bytes"] == info["library_ram"] + info["state_bytes"] + info["stack_bytes"] <= 8 * 1024
    # the stack painted under QEMU: within the static worst plus the main's timing wrapper
    measured = stand_in["target"].info["stack_step_bytes"]
    assert info["stack_path"][0][1] < measured <= info["stack_bytes"] + 32


@needs_tools
def test_each_step_takes_under_a_tenth_of_the_period_at_168_mhz(stand_in):
    outputs, instructions = stand_in["target"]
    run = stand_in["target"].info
    assert outputs.shape == instructions.shape == (STEPS,)
    assert run["calibration"] == {n: 2 * n + 3 for n in (1, 10, 1000, 100000)}  # counted to the instruction
    assert run["control_rate_hz"] == 200.0
    assert 50 < run["instructions_mean"] <= run["instructions_max"] == instructions.max() <= 0.1 * PERIOD_INSTRUCTIONS
    assert run["us_max"] == pytest.approx(instructions.max() / 168.0)
    assert np.any(outputs["saturated"]) and not np.all(outputs["saturated"])  # the readings reach the limit


@needs_tools
def test_qemu_and_host_agree_to_the_math_librarys_last_bits(stand_in):
    """newlib's sinf and atan2f (fdlibm) and glibc's differ by an ulp on a few arguments: the
    streams differ on a few steps by a few float32 ulps, never in a saturation."""
    target, host = stand_in["target"].outputs, stand_in["host"]
    same = pil.compare(target, host)
    assert "saturated" not in same["fields"]
    for name in pil.OUTPUT_FIELDS[:-1]:
        np.testing.assert_allclose(target[name], host[name], rtol=1e-5, atol=1e-6, err_msg=name)
    assert all(f["steps"] < STEPS // 10 for f in same["fields"].values()), same


@needs_tools
def test_without_the_math_library_the_bits_are_the_same(stand_in):
    directory = write_stand_in(stand_in["root"] / "arithmetic", ARITHMETIC_ONLY)
    out = stand_in["root"] / "arithmetic-build"
    target = pil.run(pil.build(directory, out)["image"], stand_in["readings"], timeout=20).outputs
    host = pil.run_host(pil.build_host(directory, out), stand_in["readings"], timeout=20)
    assert pil.compare(target, host) == {"identical": True, "fields": {}}


@needs_tools
def test_what_a_user_can_get_wrong_is_one_line(stand_in, tmp_path):
    broken = write_stand_in(tmp_path / "broken")
    (broken / "mtwip_control.c").write_text(CONTROL_C.replace("out[2] = u;", "out[2] = v;"))
    with pytest.raises(TwinError, match=r"does not compile for the Cortex-M4F .*'v' undeclared") as e:
        pil.build(broken, tmp_path / "b")
    assert "\n" not in str(e.value)
    short = tmp_path / "short.bin"
    short.write_bytes(stand_in["readings"].read_bytes()[:-7])
    with pytest.raises(TwinError, match=r"exit 2\): PIL: the readings file is not a 40-byte header"):
        pil.run(stand_in["info"]["image"], short, timeout=20)
    with pytest.raises(TwinError, match=r"did not finish under QEMU in 0.01 s"):
        pil.run(stand_in["info"]["image"], stand_in["readings"], timeout=0.01)


DISASSEMBLY = """
08000100 <step>:
 8000100:\tpush\t{r4, r5, lr}
 8000102:\tvpush\t{d8-d9}
 8000106:\tsub\tsp, #20
 8000108:\tbl\t8000200 <leaf>
 800010c:\tbl\t8000300 <tail>
 8000110:\tbeq.n\t8000100 <step>
 8000112:\tpop\t{r4, r5, pc}
08000200 <leaf>:
 8000200:\tbx\tlr
08000300 <tail>:
 8000300:\tstr.w\tlr, [sp, #-4]!
 8000304:\tsub.w\tsp, sp, #1024
 8000308:\tb.w\t8000400 <far>
08000400 <far>:
 8000400:\tpush\t{r3, lr}
 8000402:\tblx\tr3
 8000404:\tpop\t{r3, pc}
 8000406:\t.word\t0x12345678
"""


def test_the_stack_tree_sums_frames_along_calls_and_tail_calls():
    tree = pil.stack_tree(DISASSEMBLY, {"step": (64, "static")}, "step")
    assert tree["path"] == [("step", 64, "su"), ("tail", 1028, "binary"), ("far", 8, "binary")]
    assert tree["bytes"] == 1100 and not tree["exact"] and tree["notes"] == ["far: an indirect call"]
    assert pil.stack_tree(DISASSEMBLY, {}, "step")["path"][0] == ("step", 12 + 16 + 20, "binary")
    with pytest.raises(TwinError, match="mtwip_step is not in the image"):
        pil.stack_tree(DISASSEMBLY, {})


@needs_tools
def test_the_exported_ekf_and_it2_cascade_on_a_cortex_m4(tmp_path):
    """The real thing: paper-exp3's IT2 cascade with the EKF, exported in float32, on the emulated
    Cortex-M4F over a second of the twin's readings (what 'twin pil' does): flash ≤ 64 kB, RAM ≤
    8 kB, every step under a tenth of the 5 ms period at 168 MHz; its duties are the host float32
    build's, a PWM step apart at most on a few steps (the maths library's last bits)."""
    from twin.workflows.export import export
    from twin.workflows.pil import FLASH_BYTES, PERIOD_SHARE, RAM_BYTES, run_pil

    export("paper-exp3", "it2", "ekf", "float32", tmp_path / "fw", seconds=0.05)
    r = run_pil(tmp_path / "fw", seconds=1.0)
    b, q, c = r["build"], r["qemu"], r["compare"]
    assert r["steps"] == 201
    assert b["library_flash"] <= FLASH_BYTES and b["ram_bytes"] <= RAM_BYTES, (b["library_flash"], b["ram_bytes"])
    assert q["period_share"] <= PERIOD_SHARE, (q["instructions_max"], q["period_share"])
    duty = c["fields"].get("duty")
    assert duty is None or (duty["max_abs"] <= 1.0 / 1023 + 1e-6 and duty["steps"] <= 5), duty
    assert "saturated" not in c["fields"]


@needs_tools
def test_a_coasting_step_fits_the_period_on_a_cortex_m4(tmp_path):
    """The costliest steps: sensor-faults' IMU outliers and dropout, where an IMU step is tried and
    refused and the model then stands in with the 21-state covariance (the lean EKF of a float32
    export): every step under a tenth of the 5 ms period at 168 MHz, RAM ≤ 8 kB."""
    import dataclasses

    from twin.scenarios import load_scenario
    from twin.sim.simulate import simulate
    from twin.workflows.export import export
    from twin.workflows.pil import PERIOD_SHARE, RAM_BYTES, run_pil

    seconds = 6.0  # through the gyro spikes (2-4 s) and the IMU dropout (5 s)
    spec = dataclasses.replace(load_scenario("sensor-faults").run_spec("it2"), duration=seconds)
    ekf = spec.build_estimator()
    simulate(spec, estimator=ekf)
    stats = ekf.stats()
    assert stats["predict_only_steps"] - stats["unchanged_encoder_samples"] >= 40, stats  # the twin's EKF coasts
    export("sensor-faults", "it2", "ekf", "float32", tmp_path / "fw", seconds=0.05)
    assert json.loads((tmp_path / "fw" / "export.json").read_text())["arithmetic"] == "lean"
    r = run_pil(tmp_path / "fw", seconds=seconds)
    b, q = r["build"], r["qemu"]
    assert b["ram_bytes"] <= RAM_BYTES, b["ram_bytes"]
    assert q["period_share"] <= PERIOD_SHARE, (q["instructions_max"], q["period_share"])
    # the window held coasting steps: the costliest are well above a regular step's
    assert q["instructions_max"] > 1.5 * q["instructions_mean"], (q["instructions_max"], q["instructions_mean"])
