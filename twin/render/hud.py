"""The heads-up overlay of a video panel, drawn with OpenCV (Hershey fonts: ASCII only).

Top left, on a darkened box: the panel's label (controller), the plant in orange when it is
not the PyBullet twin (the analytic model of equation (1), or a user's plant by name), the
simulated time (s), the body pitch θ (rad), the travelled distance p = r ψ (m) and the
heading α (rad), in the project's SI units like every figure and file,
each with the experiment's target where it has one, the estimator's pitch θ̂ (rad, cyan like
the ghost of the body drawn at the estimate), the sensor faults acting (violet),
and, once the run has ended early, why (fell / diverged) in red.

Top right, on a box of its own: the key to what is drawn over the picture (:func:`legend_lines`),
each entry in its marker's colour beside a small copy of the marker: the cyan ghost (the body
where the estimator puts it), the green ring and arrow (the position and heading targets), the
orange cross and line (the start and the path since) and, while a push acts, the magenta arrow with the push's size and direction. Entries are shown
only when their marker is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

WHITE = (245, 245, 245)  # BGR
GREY = (190, 190, 190)
YELLOW = (80, 220, 255)
RED = (60, 60, 240)
VIOLET = (230, 130, 200)  # the figure's fault shading, in BGR
ORANGE = (60, 170, 255)  # the plant, when it is not the PyBullet twin
CYAN = (255, 255, 0)  # the estimator's ghost (twin.render.panels.GHOST_BGR)
GREEN = (40, 200, 40)  # the targets on the floor (twin.render.panels.TARGET_BGR)
MAGENTA = (255, 0, 255)  # a push acting (twin.render.panels.PUSH_BGR)
PATH = (0, 140, 255)  # the start and the path since, on the floor (twin.render.panels.PATH_BGR)
START_SHOWN_M = 0.05  # m: the start and the path are drawn once the robot is this far from the start
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
    push: str = ""  # the push acting now (:func:`push_caption`, e.g. "12 N forward"); "" for none
    from_start: float = 0.0  # m, the axle's distance from where it started (the start drawn from START_SHOWN_M)


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


_DIRECTIONS = (("forward", "backward"), ("left", "right"), ("up", "down"))


def push_caption(fx: float, fy: float, fz: float, alpha: float) -> str:
    """A push force (N, world frame) in words, in the robot's frame at heading ``alpha`` (rad):
    its size and the direction of its largest part, e.g. ``"12 N forward"``; "" for none."""
    size = math.sqrt(fx * fx + fy * fy + fz * fz)
    if size == 0.0:
        return ""
    parts = (fx * math.cos(alpha) + fy * math.sin(alpha), -fx * math.sin(alpha) + fy * math.cos(alpha), fz)
    j = max(range(3), key=lambda i: abs(parts[i]))
    return f"{size:.3g} N {_DIRECTIONS[j][0 if parts[j] >= 0 else 1]}"


def legend_lines(s: HudState) -> list[tuple[str, tuple[int, int, int], str]]:
    """The key to the markers drawn over the picture at this frame: (text, BGR colour, marker
    shape: "box", "ring", "arrow" or "path"), one entry per marker shown (as
    :func:`twin.render.panels.draw_markers` draws them): the estimator's ghost (with an
    estimate), the position target's ring, the heading target's arrow, the start and the
    path since (once the robot is :data:`START_SHOWN_M` from it), and a push while it acts."""
    out = []
    if s.theta_est is not None:
        out.append(("estimator's body (ghost)", CYAN, "box"))
    if s.p_d is not None:
        out.append((f"position target {s.p_d:.2f} m" + (" ahead" if s.alpha_d is not None else ""), GREEN, "ring"))
    if s.alpha_d is not None:
        out.append((f"heading target {s.alpha_d:.2f} rad", GREEN, "arrow"))
    if s.from_start >= START_SHOWN_M:
        out.append(("start, path since", PATH, "path"))
    if s.push:
        out.append((f"push {s.push}", MAGENTA, "arrow"))
    return out


def _darken(img: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> None:
    box = img[y0:y1, x0:x1]
    box[:] = (box.astype(np.uint16) * int(BOX_DARKEN * 256) >> 8).astype(np.uint8)


def _layout(lines: list[str], scale: float, thick: int):
    """(sizes, step, pad, width, height) in px of a box of text lines."""
    import cv2

    sizes = [cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0] for text in lines]
    step = int(round(max(th for _, th in sizes) * 1.7)) + 1
    pad = max(3, int(round(6 * scale / 0.45)))
    return sizes, step, pad, 2 * pad + max(tw for tw, _ in sizes), 2 * pad + step * len(lines)


def draw_hud(img: np.ndarray, s: HudState) -> np.ndarray:
    """Draw the overlay of ``s`` on the BGR picture ``img`` (in place) and return it: the
    text box at the top left, the markers' key (:func:`draw_legend`) at the top right."""
    import cv2

    h, w = img.shape[:2]
    scale = max(0.25, 0.45 * min(h / 480.0, w / 640.0))
    thick = 1 if scale < 0.8 else 2
    font = cv2.FONT_HERSHEY_SIMPLEX
    lines = hud_lines(s)
    sizes, step, pad, bw, bh = _layout([t for t, _ in lines], scale, thick)
    x1, y1 = min(w, bw), min(h, bh)
    _darken(img, 0, 0, x1, y1)
    for i, (text, colour) in enumerate(lines):
        y = pad + step * (i + 1) - (step - sizes[i][1]) // 2
        cv2.putText(img, text, (pad, y), font, scale, colour, thick, cv2.LINE_AA)
    draw_legend(img, s, (x1, y1))
    return img


def draw_legend(img: np.ndarray, s: HudState, hud_box: tuple[int, int] = (0, 0)) -> tuple[int, int, int, int] | None:
    """Draw the markers' key (:func:`legend_lines`) on ``img`` (in place): a darkened box at the
    top right, or under the text box (whose bottom right corner is ``hud_box``, px) where the
    two would touch. Each entry: a small copy of its marker, then its text, in its colour.
    Returns the box (x0, y0, x1, y1) px, or None when no marker is shown."""
    import cv2

    entries = legend_lines(s)
    if not entries:
        return None
    h, w = img.shape[:2]
    scale = max(0.25, 0.45 * min(h / 480.0, w / 640.0))
    thick = 1 if scale < 0.8 else 2
    sizes, step, pad, bw, bh = _layout([t for t, _, _ in entries], scale, thick)
    mark = int(round(step * 1.2))  # px: the marker's width
    bw += mark + pad
    if w - bw - pad > hud_box[0]:
        x0, y0 = w - bw, 0
    else:  # no room beside the text box: under it
        x0, y0 = 0, hud_box[1] + pad
    x1, y1 = min(w, x0 + bw), min(h, y0 + bh)
    if x1 <= x0 or y1 <= y0:
        return None
    _darken(img, x0, y0, x1, y1)
    for i, (text, colour, shape) in enumerate(entries):
        base = y0 + pad + step * (i + 1) - (step - sizes[i][1]) // 2  # the text's baseline
        cy = base - sizes[i][1] // 2  # the middle of the text's height
        mx0, mx1 = x0 + pad, x0 + pad + mark
        half = max(2, sizes[i][1] // 2)
        if shape == "box":
            cv2.rectangle(img, (mx0 + 1, cy - half), (mx1 - 1, cy + half), colour, 1, cv2.LINE_AA)
        elif shape == "ring":
            cv2.circle(img, ((mx0 + mx1) // 2, cy), half, colour, thick, cv2.LINE_AA)
        elif shape == "path":  # a cross, and a line from it
            c = mx0 + half
            cv2.line(img, (c - half, cy - half), (c + half, cy + half), colour, thick, cv2.LINE_AA)
            cv2.line(img, (c - half, cy + half), (c + half, cy - half), colour, thick, cv2.LINE_AA)
            cv2.line(img, (c, cy), (mx1, cy), colour, thick, cv2.LINE_AA)
        else:
            cv2.arrowedLine(img, (mx0, cy), (mx1, cy), colour, thick + 1, cv2.LINE_AA, tipLength=0.4)
        cv2.putText(img, text, (mx1 + pad, base), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)
    return x0, y0, x1, y1
