"""The robot-logs how-to's hobby recordings (docs/howto/hobby-robot/*.csv) are what the
independent simulator writes for them (tests/foreign/hobby_recording.py), byte for byte, and
look like a hobby firmware's log: whole codes within the sensors' ranges, a millisecond clock
stepping 30–33 ms, the mirrored right encoder counting down when the robot rolls forward."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foreign import hobby_recording as hr

DOCS = Path(__file__).resolve().parent.parent / "docs" / "howto" / "hobby-robot"


@pytest.mark.parametrize("name", sorted(hr.RECORDINGS))
def test_the_published_recording_is_the_generators(name, tmp_path):
    made = hr.write(tmp_path / name, hr.RECORDINGS[name])
    assert (DOCS / name).read_bytes() == made.read_bytes(), (
        f"docs/howto/hobby-robot/{name} differs from what tests/foreign/hobby_recording.py writes: "
        f"regenerate it with `cd tests && python -m foreign.hobby_recording ../docs/howto/hobby-robot`")


@pytest.mark.parametrize("name", sorted(hr.RECORDINGS))
def test_the_recording_looks_like_a_firmwares_log(name):
    lines = (DOCS / name).read_text(encoding="utf-8").splitlines()
    assert lines[0] == ",".join(hr.HEADER)
    d = np.array([[int(v) for v in ln.split(",")] for ln in lines[1:]])
    dt = np.diff(d[:, 0])
    assert d[0, 0] == 0 and dt.min() >= 30 and dt.max() <= 33
    assert np.abs(d[:, 1:7]).max() <= 32768 and np.abs(d[:, 9:11]).max() <= hr.PWM_MAX
    # rolling forward overall: the left count goes up, the mirrored right one down, by about as much
    fwd_l, fwd_r = d[-1, 7] - d[0, 7], d[-1, 8] - d[0, 8]
    assert np.sign(fwd_l) == -np.sign(fwd_r) != 0
    # at the start the robot lies on its front, tilted about 0.5 rad: gravity has a forward share
    # on the chip's Y (forward) axis, read as a negative specific force, and none on X (but its
    # vibration noise, σ ≈ 0.06 g)
    f = d[0, 1:4] / hr.ACCEL_LSB
    assert f[1] < -0.4 and abs(f[0]) < 0.25 and 0.75 < f[2] < 0.9
