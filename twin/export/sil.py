"""Software in the loop: an export directory compiled with the host's C compiler and run as the
twin's controller or estimator (the ``export:DIR`` kinds of :mod:`twin.registry`).

:class:`ExportedController` calls the export's ``mtwip_control`` on the twin's estimate and
returns the torques as the built-in controllers do; :class:`ExportedEstimator` feeds the sensor
suite's readings (or a log's) to ``mtwip_estimator_start``/``mtwip_estimator_step``. By default
the C's driver law then sets the PWM duties from the shaft speeds it estimates, as the firmware
does, and those drive the twin's motors; with ``drive = "torque"`` the twin's driver turns the
torques into duties with the true shaft speeds, as for every other controller, and a float64
export's run is the Python path's bit for bit.

The library is compiled once per content (the sources, the compiler and its flags) into the
twin's cache directory (:func:`twin.controllers.design_cache.cache_dir`, ``export/``), so the
workers of a sweep share it.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

from twin.errors import TwinError
from twin.export.generate import LIBRARY, read_manifest
from twin.protocols import Targets

FLAGS = ("-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic")
ESTIMATE_SIGNALS = ("u", "theta_off", "u_alpha")


def host_compiler() -> str:
    """``$CC``, else the first of cc, gcc, clang on PATH; a one-line error without one."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    raise TwinError("no C compiler found (looked for $CC, cc, gcc, clang); install one (e.g. gcc) to run an export "
                    "in the loop")


def compiler_output(text: str, lines: int = 8) -> str:
    """A compiler's complaint, its first ``lines`` lines joined as one."""
    kept = [ln.strip() for ln in text.strip().splitlines() if ln.strip()][:lines]
    return " | ".join(kept) if kept else "(no output)"


def _cache_root() -> Path:
    # only: the cache's location, shared with the designs
    from twin.controllers.design_cache import cache_dir

    return cache_dir() / "export"


def compile_library(directory) -> tuple[Path, dict]:
    """(the shared library, the manifest) of an export directory, compiled if not cached."""
    d = Path(directory).resolve()
    doc = read_manifest(d)
    cc = host_compiler()
    h = hashlib.sha256()
    try:
        version = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        version = cc
    h.update(version.encode() + repr(FLAGS).encode())
    for name in LIBRARY:
        h.update(name.encode() + b"\0" + (d / name).read_bytes() + b"\0")
    key = h.hexdigest()[:24]
    out = _cache_root() / key / "libmtwip.so"
    if out.is_file():
        return out, doc
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f"libmtwip.{os.getpid()}.tmp.so")
    sources = [str(d / n) for n in LIBRARY if n.endswith(".c")]
    try:
        r = subprocess.run([cc, *FLAGS, "-fPIC", "-shared", "-I", str(d), "-o", str(tmp), *sources, "-lm"],
                           capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        raise TwinError(f"compiling export {str(d)!r} took over 300 s; stopped") from None
    if r.returncode != 0:
        tmp.unlink(missing_ok=True)
        raise TwinError(f"export {str(d)!r} does not compile ({Path(cc).name} exit {r.returncode}): "
                        f"{compiler_output(r.stderr or r.stdout)}")
    os.replace(tmp, out)  # atomic: a sweep's workers may compile the same library at once
    return out, doc


class _Library:
    """The compiled export and its C types (double or float, as the export's precision)."""

    def __init__(self, directory):
        path, self.manifest = compile_library(directory)
        self.directory = str(Path(directory))
        self.lib = lib = ctypes.CDLL(str(path))
        real = self.real = ctypes.c_float if self.manifest["precision"] == "float32" else ctypes.c_double

        class Sample(ctypes.Structure):
            _fields_ = [("gyro", real * 3), ("accel", real * 3), ("encoder", real * 2), ("has_gyro", ctypes.c_uint8),
                        ("has_accel", ctypes.c_uint8), ("has_encoder", ctypes.c_uint8)]

        class TargetsC(ctypes.Structure):
            _fields_ = [("has_position", ctypes.c_uint8), ("position", real), ("has_heading", ctypes.c_uint8),
                        ("heading", real)]

        self.Sample, self.Targets = Sample, TargetsC
        self.vec6, self.vec5, self.vec2 = real * 6, real * 5, real * 2
        lib.mtwip_estimator_size.restype = ctypes.c_uint32
        lib.mtwip_motor_duty.restype = ctypes.c_uint8
        lib.mtwip_motor_duty.argtypes = (real, real, ctypes.POINTER(real))
        self.estimator_size = int(lib.mtwip_estimator_size())

    def targets(self, targets) -> "ctypes.Structure":
        p, h = targets.position, targets.heading
        return self.Targets(p is not None, 0.0 if p is None else p, h is not None, 0.0 if h is None else h)

    def duty(self, torque: float, omega: float) -> tuple[float, bool]:
        """The export's driver law: (duty, saturated) for a torque (N·m) at a shaft speed (rad/s)."""
        d = self.real()
        sat = self.lib.mtwip_motor_duty(torque, omega, ctypes.byref(d))
        return float(d.value), bool(sat)


_LOADED: dict[str, _Library] = {}


def load(directory) -> _Library:
    """The export in ``directory`` compiled and loaded (once per process and content)."""
    key = str(Path(directory).resolve())
    lib = _LOADED.get(key)
    if lib is None:
        lib = _LOADED[key] = _Library(directory)
    return lib


DRIVES = ("duty", "torque")


class ExportedController:
    """An export's controllers as a :class:`twin.protocols.Controller`, from the C ``mtwip_control``.

    ``drive = "duty"`` (the firmware as a whole): the C's driver law (``mtwip_drive``) turns the
    torques into the PWM duties with the shaft speeds it takes from the estimate, and those duties
    drive the twin's motors (:attr:`drives_duty`); the output is ``(ul, ur, u, θ_off, u_α, duty_l,
    duty_r, saturated_l, saturated_r)``. ``drive = "torque"``: ``(ul, ur, u, θ_off, u_α)`` (N·m, N·m,
    N·m, rad, N·m per wheel), turned into duties by the twin's driver with the true shaft speeds, as
    for every other controller: the run is then the Python path's, bit for bit (float64).
    """

    def __init__(self, directory, drive: str = "duty"):
        if drive not in DRIVES:
            raise TwinError(f"drive must be one of {', '.join(DRIVES)}, got {drive!r}")
        self._c = load(directory)
        self.directory = self._c.directory
        self.manifest = self._c.manifest
        self.drive = drive
        self.drives_duty = drive == "duty"
        self.signals = ESTIMATE_SIGNALS + (("duty_cmd_l", "duty_cmd_r", "saturated_cmd_l", "saturated_cmd_r")
                                           if self.drives_duty else ())
        self.signal_units = {"u": "N·m", "theta_off": "rad", "u_alpha": "N·m", "duty_cmd_l": "1", "duty_cmd_r": "1",
                             "saturated_cmd_l": "bool", "saturated_cmd_r": "bool"}
        lib = self._c.lib
        self._control, self._drive = lib.mtwip_control, lib.mtwip_drive
        self._x, self._out = self._c.vec6(), self._c.vec5()
        self._duty, self._sat = self._c.vec2(), (ctypes.c_uint8 * 2)()
        self._t = self._c.targets(Targets())
        self._for = None

    def design_digest(self) -> str:
        """The export's library digest (its files' SHA-256): equal digests, the same C."""
        return self.manifest["library_digest"]

    def reset(self, targets) -> None:
        loops = self.manifest.get("loops", {})
        for name, value in (("position", targets.position), ("heading", targets.heading)):
            if value is not None and not loops.get(name, False):
                raise TwinError(f"export {self.directory!r} has no {name} loop (its scenario "
                                f"{self.manifest.get('scenario', '?')!r} set no {name} target) and this run sets one; "
                                f"export from a scenario with a {name} target")
        self._t = self._c.targets(targets)
        self._for = targets

    def __call__(self, estimate, targets):
        if targets is not self._for:
            self._t = self._c.targets(targets)
            self._for = targets
        x = self._x
        x[0], x[1], x[2], x[3], x[4], x[5] = estimate[:6]
        out = self._out
        self._control(x, ctypes.byref(self._t), out)
        if not self.drives_duty:
            return out[0], out[1], out[2], out[3], out[4]
        duty, sat = self._duty, self._sat
        self._drive(x, out, duty, sat)
        return out[0], out[1], out[2], out[3], out[4], duty[0], duty[1], float(sat[0]), float(sat[1])



class ExportedEstimator:
    """An export's estimator as a :class:`twin.protocols.Estimator`: the readings in, the
    estimate [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s) out, from the C ``mtwip_estimator_start``/``step``."""

    def __init__(self, directory, control_rate: float | None = None):
        c = self._c = load(directory)
        self.directory = c.directory
        self.manifest = c.manifest
        rate = self.manifest.get("control_rate_hz")
        if control_rate is not None and rate is not None and abs(float(rate) - float(control_rate)) > 1e-9 * rate:
            raise TwinError(f"export {self.directory!r} runs at {rate:g} Hz and this run's control rate is "
                            f"{control_rate:g} Hz; export for this rate (the scenario's rates.control)")
        self._state = ctypes.create_string_buffer(c.estimator_size)
        self._sample = c.Sample()
        self._x = c.vec6()
        self._cmd = c.vec2()
        self._start, self._step = c.lib.mtwip_estimator_start, c.lib.mtwip_estimator_step
        c.lib.mtwip_estimator_init(self._state)

    def set_sampling(self, imu: str = "mean", commands: str = "held", periods: str = "constant") -> None:
        """A log's sampling (:class:`twin.protocols.Estimator`): the export runs the twin's own (IMU
        means over the period, commands held, every period the control period); any other is refused."""
        if (imu, commands, periods) != ("mean", "held", "constant"):
            raise TwinError(f"export {self.directory!r} estimates from IMU means over each period, commands held and "
                            f"periods of 1 / control rate; this log has imu {imu!r}, commands {commands!r}, periods "
                            f"{periods!r}: replay it with the Python estimator")

    def _fill(self, meas) -> None:
        s = self._sample
        g, a, e = meas.gyro, meas.accel, meas.encoders
        s.has_gyro = g is not None
        if g is not None:
            s.gyro[0], s.gyro[1], s.gyro[2] = g[0], g[1], g[2]
        s.has_accel = a is not None
        if a is not None:
            s.accel[0], s.accel[1], s.accel[2] = a[0], a[1], a[2]
        s.has_encoder = e is not None
        if e is not None:
            s.encoder[0], s.encoder[1] = e[0], e[1]

    def start(self, meas):
        self._fill(meas)
        x = self._x
        self._start(self._state, ctypes.byref(self._sample), x)
        return x[0], x[1], x[2], x[3], x[4], x[5]

    def step(self, meas, command):
        self._fill(meas)
        cmd, x = self._cmd, self._x
        cmd[0], cmd[1] = command[0], command[1]
        self._step(self._state, ctypes.byref(self._sample), cmd, x)
        return x[0], x[1], x[2], x[3], x[4], x[5]


def build_controller(directory, context=None, drive: str = "duty"):
    """The ``export:DIR`` controller kind's factory (``drive``: see :class:`ExportedController`)."""
    return ExportedController(directory, drive)


def build_estimator(directory, context=None):
    """The ``export:DIR`` estimator kind's factory."""
    if context is not None and context.sensors is None:
        raise TwinError(f"export {str(directory)!r}'s estimator needs sensors, but sensing is ideal")
    return ExportedEstimator(directory, None if context is None else context.control_rate)


__all__ = ["ExportedController", "ExportedEstimator", "build_controller", "build_estimator", "compile_library",
           "compiler_output", "host_compiler", "load"]
