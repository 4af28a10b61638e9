"""The heads-up overlay of a video panel, drawn with OpenCV (Hershey fonts: ASCII only).

Top left, on a darkened box: the panel's label (controller), the plant in orange when it is
not the PyBullet twin (the analytic model of equation (1), or a user's plant by name), the
simulated time (s), the body pitch θ (rad), the travelled distance p = r ψ (m) and the
heading α (rad), in the project's SI units like every figure and file,
each with the experiment's target where it has one, the estimator's pitch θ̂ (rad, cyan like
the ghost of the body drawn at the estimate), the sensor faults acting (violet),
and, once the run has ended early, why (fell / diverged) in red.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WHITE = (245, 245, 245)  # BGR
GREY = (190, 190, 190)
YELLOW = (80, 220, 255)
RED = (60, 60, 240)
VIOLET = (230, 130, 200)  # the figure's fault shading, in BGR
ORANGE = (60, 170, 255)  # the plant, when it is not the PyBullet twin
CYAN = (255, 255, 0)  # the estimator's ghost (twin.render.panels.GHOST_BGR)
BOX_DARKEN = 0.45  # the box keeps this fraction of the picture's brightness


@dataclass(frozen=True)
class HudState:
    """What the overlay shows at one frame (SI units, printed as they are)."""

    label: str
    t: float  # s
    theta: float  # rad
    distance: float  # m
    alpha: float  # rad
    p_d: float | None = None  # m, target distance
    alpha_d: float | None = None  # rad, target heading
    ended: str = ""  # "" while the run goes on; else what to say (e.g. "FELL at 1.23 s")
    alarm: bool = False  # the run ended early (fell, diverged): ``ended`` in red
    fault: str = ""  # the sensor faults acting now, named (e.g. "IMU dropout"); "" for none
    theta_est: float | None = None  # rad, the estimator's pitch (None with ideal sensing)
    plant: str = ""  # what simulated the run when it is not the PyBullet twin (:func:`plant_caption`); "" for the twin


PLANT_NAME_MAX = 36  # characters of a user's plant name on the overlay (its end kept: the class's name)


def plant_caption(plant: str) -> str:
    """What the overlay says of a run's plant (:attr:`twin.sim.runs.Run.plant`): nothing for the
    PyBullet twin, ``"analytic model (eq. 1)"`` for the analytic one, else the user's plant
    as the run names it (its module and class), in ASCII (the Hershey fonts have nothing
    else) and at most :data:`PLANT_NAME_MAX` characters."""
    if not plant or plant == "twin":
        return ""
    if plant == "analytic":
        return "analytic model (eq. 1)"
    text = "".join(c if " " <= c <= "~" else "?" for c in " ".join(str(plant).split()))
    return text if len(text) <= PLANT_NAME_MAX else "..." + text[-(PLANT_NAME_MAX - 3):]


def _num(v: float, decimals: int) -> float:
    """``v`` rounded, without a negative zero."""
    return round(v, decimals) + 0.0


def hud_lines(s: HudState) -> list[tuple[str, tuple[int, int, int]]]:
    """The overlay's text lines and their BGR colours."""
    lines = [(s.label, YELLOW)]
    if s.plant:
        lines.append((f"plant: {s.plant}", ORANGE))
    lines += [(f"t       {_num(s.t, 2):6.2f} s", WHITE), (f"pitch   {_num(s.theta, 3):+6.3f} rad", WHITE)]
    if s.theta_est is not None:
        lines.append((f"  est.  {_num(s.theta_est, 3):+6.3f} rad", CYAN))
    dist = f"dist    {_num(s.distance, 3):+6.3f} m"
    if s.p_d is not None:
        dist += f"  (target {s.p_d:.2f} m)"
    head = f"heading {_num(s.alpha, 3):+6.3f} rad"
    if s.alpha_d is not None:
        head += f"  (target {s.alpha_d:.2f} rad)"
    lines += [(dist, WHITE), (head, WHITE)]
    if s.fault:
        lines.append((f"fault: {s.fault}", VIOLET))
    if s.ended:
        lines.append((s.ended, RED if s.alarm else GREY))
    return lines


def draw_hud(img: np.ndarray, s: HudState) -> np.ndarray:
    """Draw the overlay of ``s`` on the BGR picture ``img`` (in place) and return it."""
    import cv2

    h, w = img.shape[:2]
    scale = max(0.25, 0.45 * min(h / 480.0, w / 640.0))
    thick = 1 if scale < 0.8 else 2
    font = cv2.FONT_HERSHEY_SIMPLEX
    lines = hud_lines(s)
    sizes = [cv2.getTextSize(text, font, scale, thick)[0] for text, _ in lines]
    step = int(round(max(th for _, th in sizes) * 1.7)) + 1
    pad = max(3, int(round(6 * scale / 0.45)))
    x1 = min(w, 2 * pad + max(tw for tw, _ in sizes))
    y1 = min(h, 2 * pad + step * len(lines))
    box = img[0:y1, 0:x1]
    box[:] = (box.astype(np.uint16) * int(BOX_DARKEN * 256) >> 8).astype(np.uint8)
    for i, (text, colour) in enumerate(lines):
        y = pad + step * (i + 1) - (step - sizes[i][1]) // 2
        cv2.putText(img, text, (pad, y), font, scale, colour, thick, cv2.LINE_AA)
    return img
