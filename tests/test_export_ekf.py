"""The EKF as C (:mod:`twin.export.ekf`): compiled with the host's compiler, it gives the twin's
estimates step for step on the readings and commands of a twin run (paper-exp3; sensor-faults
through its gyro spikes, which the filter rejects and coasts over, and its 0.2 s IMU dropout); the
float32 build compiles clean; the same estimator gives the same bytes; an option the C does not
implement is refused in one line."""
from __future__ import annotations

import ctypes
import dataclasses
import shutil
import subprocess
from importlib import resources

import numpy as np
import pytest

from twin.errors import TwinError
from twin.export import ekf as ekf_export
from twin.scenarios import load_scenario
from twin.sim.simulate import simulate

COMPILERS = [c for c in ("cc", "gcc", "clang") if shutil.which(c)]
pytestmark = pytest.mark.skipif(not COMPILERS, reason="no C compiler (cc, gcc or clang) on this machine")
STRICT = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]

# a stand-in for the generated mtwip_params.h: the precision and the math functions the EKF uses
PARAMS = """#ifndef MTWIP_PARAMS_H
#define MTWIP_PARAMS_H
#include <math.h>
typedef %(real)s mtwip_real;
#define MTWIP_R(x) ((mtwip_real)(x))
#define MTWIP_FLOAT32 %(f32)d
#define MTWIP_SIN sin%(s)s
#define MTWIP_COS cos%(s)s
#define MTWIP_TAN tan%(s)s
#define MTWIP_ATAN2 atan2%(s)s
#define MTWIP_SQRT sqrt%(s)s
#define MTWIP_FABS fabs%(s)s
#define MTWIP_EXP exp%(s)s
#define MTWIP_POW pow%(s)s
#define MTWIP_ERFC erfc%(s)s
#define MTWIP_HYPOT hypot%(s)s
#define MTWIP_ISFINITE(x) isfinite(x)
#include "mtwip_estimator.h"
#endif
"""

# the readings and commands of a run in, the estimates out: mtwip_estimator_start, then _step
DRIVER = r"""#include <string.h>
#include "mtwip.h"
static mtwip_estimator_t E;
int ekf_replay(int n, const double *gyro, const double *accel, const double *enc, const unsigned char *has,
               const double *cmd, double *out) {
    int k, i;
    mtwip_estimator_init(&E);
    for (k = 0; k < n; k++) {
        mtwip_sample_t s;
        mtwip_real c[2], x[6];
        memset(&s, 0, sizeof s);
        for (i = 0; i < 3; i++) {
            s.gyro[i] = (mtwip_real)gyro[3 * k + i];
            s.accel[i] = (mtwip_real)accel[3 * k + i];
        }
        s.encoder[0] = (mtwip_real)enc[2 * k];
        s.encoder[1] = (mtwip_real)enc[2 * k + 1];
        s.has_gyro = has[3 * k];
        s.has_accel = has[3 * k + 1];
        s.has_encoder = has[3 * k + 2];
        c[0] = (mtwip_real)cmd[2 * k];
        c[1] = (mtwip_real)cmd[2 * k + 1];
        if (k == 0)
            mtwip_estimator_start(&E, &s, x);
        else
            mtwip_estimator_step(&E, &s, c, x);
        for (i = 0; i < 6; i++) out[6 * k + i] = (double)x[i];
    }
    return 0;
}
"""


class Recording:
    """The twin's EKF, recording what the loop gives it and what it answers."""

    def __init__(self, inner):
        self.inner = inner
        self.log = []

    def start(self, meas):
        est = self.inner.start(meas)
        self.log.append((meas.gyro, meas.accel, meas.encoders, None, tuple(est)))
        return est

    def step(self, meas, command):
        est = self.inner.step(meas, command)
        self.log.append((meas.gyro, meas.accel, meas.encoders, (float(command[0]), float(command[1])), tuple(est)))
        return est

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _run(scenario: str, seconds: float):
    """(a fresh EKF as the twin builds it for the run, the recording, the run's EKF)"""
    spec = dataclasses.replace(load_scenario(scenario).run_spec("it2"), duration=seconds)
    rec = Recording(spec.build_estimator())
    simulate(spec, estimator=rec)
    return spec.build_estimator(), rec.log, rec.inner


def _write(estimator, precision: str, d):
    f32 = precision == "float32"
    for name, text in ekf_export.emit(estimator, precision).items():
        (d / name).write_text(text)
    (d / "mtwip.h").write_text(resources.files("twin.export").joinpath("c", "mtwip.h").read_text(encoding="utf-8"))
    (d / "mtwip_params.h").write_text(PARAMS % {"real": "float" if f32 else "double", "f32": int(f32),
                                                "s": "f" if f32 else ""})
    (d / "driver.c").write_text(DRIVER)


def _replay(lib, log) -> np.ndarray:
    n = len(log)
    gyro, accel, enc = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 2))
    has, cmd, out = np.zeros((n, 3), np.uint8), np.zeros((n, 2)), np.zeros((n, 6))
    for k, (g, a, e, c, _) in enumerate(log):
        for j, (v, dst) in enumerate(((g, gyro), (a, accel), (e, enc))):
            if v is not None:
                dst[k], has[k, j] = v, 1
        if c is not None:
            cmd[k] = c
    p = [np.ascontiguousarray(v).ctypes.data_as(ctypes.c_void_p) for v in (gyro, accel, enc, has, cmd, out)]
    lib.ekf_replay(ctypes.c_int(n), *p)
    return out


@pytest.mark.parametrize("scenario, seconds", [("paper-exp3", 2.5), ("sensor-faults", 5.5)])
def test_the_c_gives_the_twins_estimates_step_for_step(scenario, seconds, tmp_path):
    fresh, log, run = _run(scenario, seconds)
    if scenario == "sensor-faults":  # the faults were there: rejected gyro spikes and the dropout, coasted over
        stats = run.stats()
        assert stats["rejected"]["gyro"] > 0, stats
        assert stats["predict_only_steps"] - stats["unchanged_encoder_samples"] >= 40, stats
    _write(fresh, "float64", tmp_path)
    so = tmp_path / "libekf.so"
    r = subprocess.run([COMPILERS[0], *STRICT, "-fPIC", "-shared", "-I", str(tmp_path),
                        str(tmp_path / "mtwip_estimator.c"), str(tmp_path / "driver.c"), "-o", str(so), "-lm"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    c = _replay(ctypes.CDLL(str(so)), log)
    twin = np.array([x for *_, x in log])
    diff = np.abs(c - twin)
    worst = diff.max(axis=0)
    assert worst.max() <= 1e-9, (f"{scenario}: C against the twin's EKF, worst |diff| per state {worst}, first at step "
                                 f"{int(np.argmax(diff.max(axis=1) > 1e-9))}")


def test_the_float32_build_compiles_clean(tmp_path):
    fresh = load_scenario("sensor-faults").run_spec("it2").build_estimator()
    _write(fresh, "float32", tmp_path)
    for cc in {shutil.which(c) for c in COMPILERS}:
        r = subprocess.run([cc, *STRICT, "-Wdouble-promotion", "-c", "-I", str(tmp_path),
                            str(tmp_path / "mtwip_estimator.c"), "-o", str(tmp_path / "ekf.o")],
                           capture_output=True, text=True)
        assert r.returncode == 0, f"{cc}: {r.stderr}"


def test_the_same_estimator_gives_the_same_bytes_and_options_are_refused():
    spec = load_scenario("paper-exp3").run_spec("it2")
    a, b = spec.build_estimator(), spec.build_estimator()
    for precision in ("float64", "float32"):
        assert ekf_export.emit(a, precision) == ekf_export.emit(b, precision)
    source = ekf_export.emit(a, "float64")["mtwip_estimator.c"]
    assert "static const mtwip_ekf_config_t mtwip_ekf_config = {" in source
    b.set_sampling(imu="point")
    with pytest.raises(TwinError, match="set_sampling.*allowed"):
        ekf_export.emit(b, "float64")
    from estimation.ekf import EKFEstimator

    with pytest.raises(TwinError, match="compiled=False.*allowed"):
        ekf_export.emit(EKFEstimator(a.model, compiled=False), "float64")
