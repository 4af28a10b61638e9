"""The EKF's layout (issue 42, item 5), read from the code: no class over 500 lines in
``estimation/``, every policy threshold defined once (:data:`estimation.ekf_config.POLICY`), and
the compiled kernel configured by name from :class:`estimation.ekf_config.KernelConfig` (the
generated header current, the built kernel's fields the dataclass's, each policy number read
from the configuration, not written in the C source)."""
from __future__ import annotations

import ast
import dataclasses
import math
import os
from pathlib import Path

import numpy as np
import pytest

from estimation import ekf_config
from estimation.ekf import EKFEstimator
from estimation.ekf_config import CONFIG_FIELDS, POLICY, KernelConfig, c_header
from estimation.ekf_core import PS, TH, CompiledCore, N, _kernel, check_kernel_layout
from estimation.ekf_filter import kernel_config
from estimation.model import EstimatorModel

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "estimation"
MAX_CLASS_LINES = 500
PURE = os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0")
needs_kernel = pytest.mark.skipif(PURE or _kernel is None, reason="compiled EKF kernel not available")


def _classes():
    for path in sorted(PACKAGE.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                yield path.name, node.name, node.end_lineno - node.lineno + 1


def test_no_class_in_estimation_is_over_500_lines():
    sizes = list(_classes())
    assert any(name == "EKFEstimator" for _, name, _ in sizes)
    big = [(f, name, n) for f, name, n in sizes if n > MAX_CLASS_LINES]
    assert big == [], f"classes over {MAX_CLASS_LINES} lines: {big}"


def test_the_size_check_sees_a_long_class(tmp_path):
    body = "\n".join(f"    a{i} = {i}" for i in range(MAX_CLASS_LINES))
    tree = ast.parse(f"class Long:\n{body}\n")
    node = tree.body[0]
    assert node.end_lineno - node.lineno + 1 > MAX_CLASS_LINES


def test_every_policy_threshold_is_defined_once():
    """The names of ekf_config's thresholds are assigned a value nowhere else in estimation/
    (imported, they are the same number)."""
    names = {n for n in ekf_config.__all__ if n.isupper()}
    found = []
    for path in sorted(PACKAGE.glob("*.py")):
        if path.name == "ekf_config.py":
            continue
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, ast.AnnAssign) else []
            found += [f"{path.name}: {t.id}" for t in targets if isinstance(t, ast.Name) and t.id in names]
    assert found == []
    assert ekf_config.TILT_LIMIT == POLICY.tilt_limit and ekf_config.WATCH_WINDOW == POLICY.watch_window


def test_the_kernel_configuration_takes_the_policy_numbers():
    policy = {f.name for f in dataclasses.fields(ekf_config.Policy)}
    for f in dataclasses.fields(KernelConfig):
        if f.name in policy:
            assert f.default == getattr(POLICY, f.name), f.name


def test_the_generated_header_is_current():
    """estimation/_ekf_config.h is what ``python -m estimation.ekf_config`` writes from the
    dataclass: a field added, renamed or moved without regenerating it fails here."""
    assert ekf_config.HEADER.read_text(encoding="utf-8") == c_header()
    for name in CONFIG_FIELDS:
        assert f"S({name})" in c_header() or f"A({name}," in c_header()


def test_the_c_source_writes_no_policy_number():
    """The spellings the kernel had for the policy's numbers before they came from the
    configuration (a rule's threshold written in C would drift from POLICY unseen)."""
    src = (PACKAGE / "_ekf.c").read_text(encoding="utf-8")
    for literal in ("M_PI * M_PI / 12.0", "0.5 * M_PI", "3.5 *", "1e-10", "4.0 * c->Pg", "2.0 * acc[0]",
                    "(1.0 / 12.0)", "NCONST"):
        assert literal not in src, literal
    assert '#include "_ekf_config.h"' in src and "EKF_CONFIG(" in src


def test_a_configuration_is_typed_and_checked():
    est = EKFEstimator(EstimatorModel(), compiled=False)
    cfg = _config_of(est)
    assert isinstance(cfg, KernelConfig) and tuple(f.name for f in dataclasses.fields(cfg)) == CONFIG_FIELDS
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.dt = 1.0
    with pytest.raises(ValueError, match="gate must be a tuple of 2"):
        dataclasses.replace(cfg, gate=(1.0, 2.0, 3.0))


def _config_of(est) -> KernelConfig:
    return kernel_config(est.filter, est.gates, est.imu_gates, est.max_rejects_in_row, est.front.inside.half, 3.0)


class _FakeKernel:
    def __init__(self, names):
        self.names = names

    def config_fields(self):
        return self.names


def test_a_kernel_built_for_another_configuration_is_refused():
    check_kernel_layout(_FakeKernel(CONFIG_FIELDS))
    for names in (CONFIG_FIELDS[1:], CONFIG_FIELDS[:3] + CONFIG_FIELDS[4:3:-1] + CONFIG_FIELDS[3:4] + CONFIG_FIELDS[5:],
                  CONFIG_FIELDS + ("extra",)):
        with pytest.raises(RuntimeError, match="another configuration"):
            check_kernel_layout(_FakeKernel(names))
    with pytest.raises(RuntimeError, match="another configuration"):
        check_kernel_layout(object())  # a kernel of the positional tuple: no config_fields at all


@needs_kernel
def test_the_built_kernel_reads_the_dataclass_fields_by_name():
    assert tuple(_kernel.config_fields()) == CONFIG_FIELDS
    cfg = _config_of(EKFEstimator(EstimatorModel(), compiled=False))

    class Missing:  # every field but one
        pass

    m = Missing()
    for name in CONFIG_FIELDS[:-1]:
        setattr(m, name, getattr(cfg, name))
    with pytest.raises(AttributeError, match=CONFIG_FIELDS[-1]):
        _kernel.new(m)
    with pytest.raises(TypeError, match="KernelConfig"):
        CompiledCore(_kernel, tuple(getattr(cfg, n) for n in CONFIG_FIELDS))


# ---- each policy number the kernel uses is the configuration's: change it, the kernel follows ----
def _core(cfg: KernelConfig, theta: float = 0.0) -> CompiledCore:
    core = CompiledCore(_kernel, cfg)
    x, P = np.zeros(N), np.eye(N) * 1e-6
    x[TH] = theta
    core.set_state(x, P, (0.0, 0.0), (0.0, 0.0))
    return core


def _advance(core, cfg, sample=(0.0, 0.0, 0.0, 9.81), acc_test=(0.0, 0.0, 0.0, 0.0)):
    return core.advance(sample, None, None, cfg.mdt, (0.0, 0.0), 0, acc_test)


@needs_kernel
def test_the_kernel_takes_the_physical_range_from_its_configuration():
    cfg = _config_of(EKFEstimator(EstimatorModel(), compiled=False))
    assert _advance(_core(cfg, 0.3), cfg)[5] == 1
    narrow = dataclasses.replace(cfg, tilt_limit=0.2)
    assert _advance(_core(narrow, 0.3), narrow)[5] == -1
    tight = dataclasses.replace(cfg, tilt_var_max=1e-9)
    assert _advance(_core(tight, 0.0), tight)[5] == -1


@needs_kernel
def test_the_kernel_takes_the_trapezoid_and_the_restore_from_its_configuration():
    cfg = _config_of(EKFEstimator(EstimatorModel(), compiled=False))
    a, b = _core(cfg), _core(dataclasses.replace(cfg, trapezoid_var=0.0))
    moving = (0.0, 0.0, 5.0, 9.81)  # a forward acceleration: v changes over the step
    _advance(a, cfg, moving)
    _advance(b, cfg, moving)
    a.pull()
    b.pull()
    assert a.P[PS, PS] > b.P[PS, PS]
    odd = dataclasses.replace(cfg, restore_inflation=3.0, restore_jitter=1e-6)
    core = _core(odd)
    P0 = core.P.copy()
    x = core.x.copy()
    x[TH] = math.nan
    core._kernel.set_state(core._core, x, P0.ravel(), (0.0, 0.0), (0.0, 0.0))  # broken: not kept as good
    assert _advance(core, odd)[5] == 0
    core.pull()
    assert core.P.tobytes() == (3.0 * P0 + np.diag(np.full(N, 1e-6))).tobytes()


@needs_kernel
def test_the_kernel_takes_the_accelerometer_test_from_its_configuration():
    """With the variance factor 0 every accelerometer sample whose gyro agrees is an outlier;
    with the gyro's noise taken as nothing, no gyro agrees."""
    cfg = _config_of(EKFEstimator(EstimatorModel(), compiled=False))
    test = (cfg.imu_gate[1], 0.0, 0.0, 1.0)
    near = (0.0, 0.0, 0.0, cfg.g + 0.02)  # 0.02 m/s² off the model's specific force: no outlier
    assert _advance(_core(cfg), cfg, near, acc_test=test)[6] == 0
    eager = dataclasses.replace(cfg, accel_variance_factor=0.0)
    assert _advance(_core(eager), eager, near, acc_test=test)[6] == 1
    deaf = dataclasses.replace(eager, gyro_extrapolation_samples=0.0, g_var=1e-300)
    assert _advance(_core(deaf), deaf, (0.5, 0.0, 0.0, cfg.g + 0.02), acc_test=test)[6] == 0
