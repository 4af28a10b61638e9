"""The frames of one video panel, rendered here or in a process of their own.

A panel is one run replayed in a :class:`~twin.render.scene.Scene` of its own, with its
heads-up overlay, one BGR picture per frame time; a run that has ended holds its last
picture. Panels share nothing, so with several runs each can be rendered by a worker
process while this one composes the frames and feeds the encoder: rendering (about 20 ms
per 640x480 EGL frame here) is the video's bottleneck once H.264 encodes a frame in
2–3 ms. The pictures are the same bytes either way (tests/test_render.py).

Worker protocol (on the worker's stdout; every message is its length, 8 bytes little-endian,
then its bytes): the name of the renderer it got (``b"egl"`` or ``b"tiny"``), then one
message of ``height·width·3`` bytes per frame; on an error ``b"ERROR: "`` and one line,
and it stops. Its job, a pickle, comes on its stdin.
"""
from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np

from twin.errors import TwinError
from twin.render.hud import CYAN, GREEN, MAGENTA, PATH, START_SHOWN_M, HudState, draw_hud, push_caption
from twin.render.scene import Scene
from twin.workers import subprocess_env, subprocess_worker_init

_ERROR = b"ERROR: "


def panel_frames(scene: Scene, track, samples: dict, times: np.ndarray, hud: bool) -> Iterator[np.ndarray]:
    """The BGR panels (height, width, 3) of ``track`` (a video ``_Track``) at ``times`` (s),
    from its ``samples`` (the track sampled at ``times``), drawn in ``scene``."""
    import cv2

    held = None
    for k, tk in enumerate(times.tolist()):
        if held is not None:
            yield held
            continue
        s = samples
        rgb = scene.render(s["theta"][k], s["alpha"][k], s["x"][k], s["y"][k], s["psi_l"][k], s["psi_r"][k],
                           s["roll"][k], t=tk)
        panel = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        draw_markers(panel, scene, track, s, k)
        if hud:
            draw_hud(panel, HudState(track.label, min(tk, track.duration), s["theta"][k], s["distance"][k],
                                     s["alpha"][k], track.p_d, track.alpha_d, track.ended(tk),
                                     track.status != "ok", track.fault_at(min(tk, track.duration)),
                                     s["theta_est"][k] if "theta_est" in s else None, track.plant,
                                     push_caption(s["push_fx"][k], s["push_fy"][k], s["push_fz"][k], s["alpha"][k]),
                                     from_start(track, s, k)))
        if tk > track.duration + 1e-9:
            held = panel  # the run has ended: this panel stays as it is
        yield panel


TARGET_BGR = GREEN  # the position target on the floor, the heading target's arrow (the key: hud.legend_lines)
PATH_BGR = PATH  # the start (a cross on the floor) and the path travelled since (a line on the floor)
START_CROSS_M = 0.06  # m: half the length of each stroke of the start's cross
RING_M = 0.06  # m: the position target's ring's radius
PATH_STEP_M = 0.01  # m: the path is drawn through points this far apart along it ...
PATH_POINTS = 400  # ... and through this many at most (a longer path, a longer step)
PX_LIMIT = 1e5  # px: a point projected further out (just in front of the eye) is not drawn through
PUSH_BGR = MAGENTA  # a push acting now (no other magenta in the scene)
GHOST_BGR = CYAN  # the body where the estimator puts it (the HUD's estimate line has its colour)
GHOST_FILL = 0.15  # opacity of the ghost's faces: the body shows through in its own colour
PUSH_M_PER_N = 0.02  # m of arrow per N of push (12 N: 24 cm)
HEADING_ARROW_M = 0.3  # m
# a pixel whose surface stands higher than this above the floor hides a floor marker: 1 cm,
# and 1 cm more per 2 m from the eye (TinyRenderer's depth is about 1 mm off at 1 m)
FLOOR_TOLERANCE = 0.01  # m
FLOOR_TOLERANCE_PER_M = 0.005  # m per m
# the 12 edges of a box whose corners are numbered 4·ix + 2·iy + iz (i = 0 low, 1 high)
_BOX_EDGES = [(a, a | bit) for a in range(8) for bit in (1, 2, 4) if not a & bit]


def box_corners(box) -> np.ndarray:
    """The 8 corners (8, 3) of the box with lowest and highest corners ``box``, numbered as
    :data:`_BOX_EDGES` expects."""
    lo, hi = box
    return np.array([(hi[0] if i & 4 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 1 else lo[2])
                     for i in range(8)])


def draw_ghost(img: np.ndarray, uv: np.ndarray, thick: int) -> None:
    """A translucent box over ``img`` with its corners at the pixels ``uv`` (8, 2): faces
    filled at :data:`GHOST_FILL` opacity, every edge drawn (the far ones show through)."""
    import cv2

    if not np.isfinite(uv).all():
        return
    px = np.round(uv).astype(np.int32)
    hull = cv2.convexHull(px)
    x0, y0, bw, bh = cv2.boundingRect(hull)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x0 + bw, img.shape[1]), min(y0 + bh, img.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    roi = img[y0:y1, x0:x1]
    mask = np.zeros(roi.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, hull - (x0, y0), 255)
    tint = np.empty_like(roi)
    tint[:] = GHOST_BGR
    blend = cv2.addWeighted(roi, 1.0 - GHOST_FILL, tint, GHOST_FILL, 0.0)
    cv2.copyTo(blend, mask, roi)
    for a, b in _BOX_EDGES:
        cv2.line(img, tuple(int(v) for v in px[a]), tuple(int(v) for v in px[b]), GHOST_BGR, thick, cv2.LINE_AA)


def draw_markers(img: np.ndarray, scene: Scene, track, s: dict, k: int) -> None:
    """Draw, over the picture just taken, what the world does not show: the start (a cross on
    the floor) and the path travelled since (a line on the floor from the start to the axle),
    once the robot is :data:`twin.render.hud.START_SHOWN_M` from the start (the camera follows
    the robot, so these show the travel); the position target (a ring on the floor: without a
    heading target p_d ahead of the start along the starting heading, where the robot is to
    stop; with one, p_d − p ahead of the axle along the present heading, where p reaches p_d
    if the robot drives straight on), the heading target
    (an arrow on the floor from the axle towards α_d), the estimator's ghost (the body box
    at the estimated pitch θ̂ and heading α̂, moved along the heading by r(ψ̂ − ψ), the error
    in travelled distance; translucent cyan) and a push acting now (an arrow into the top
    of the body along the force, its length proportional to it). Floor markers follow a
    sloped floor and are hidden where the robot stands in front of them (the picture's
    depth buffer says what each pixel shows); the ghost and the push arrow are drawn over
    everything."""
    import cv2

    drawn_at = []  # pixels (column, row) the floor markers were drawn through

    def line(a, b, colour, thick, arrow=False):
        (u0, v0), (u1, v1) = scene.project(np.array([a, b]))
        if not (np.isfinite([u0, v0, u1, v1]).all() and max(abs(u0), abs(v0), abs(u1), abs(v1)) < PX_LIMIT):
            return
        p0, p1 = (int(round(u0)), int(round(v0))), (int(round(u1)), int(round(v1)))
        drawn_at.extend((p0, p1))
        if arrow:
            cv2.arrowedLine(img, p0, p1, colour, thick, cv2.LINE_AA, tipLength=0.25)
        else:
            cv2.line(img, p0, p1, colour, thick, cv2.LINE_AA)

    def polyline(xy, colour, width):
        uv = scene.project(scene.floor_points(xy))  # one projection for the whole line
        # a point behind the eye (NaN) or just in front of it (far outside the picture) breaks the line
        ok = np.isfinite(uv).all(axis=1)
        ok[ok] = (np.abs(uv[ok]) < PX_LIMIT).all(axis=1)
        drawn_at.extend(uv[ok].tolist())
        px = np.zeros(uv.shape, np.int32)
        px[ok] = np.rint(uv[ok])
        edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):  # each run of drawable points, one polyline
            if b - a >= 2:
                cv2.polylines(img, [px[a:b]], False, colour, width, cv2.LINE_AA)

    thick = max(2, int(round(img.shape[0] / 160)))
    x, y, a, roll = s["x"][k], s["y"][k], s["alpha"][k], s["roll"][k]
    x0, y0, a0 = track.start
    travelled = from_start(track, s, k) >= START_SHOWN_M
    picture = img
    if track.p_d is not None or track.alpha_d is not None or travelled:
        img = img.copy()  # floor markers go on a layer, shown where the floor shows
    if travelled:
        c, d = START_CROSS_M * np.cos(a0 + np.pi / 4), START_CROSS_M * np.sin(a0 + np.pi / 4)
        polyline([(x0 - c, y0 - d), (x0 + c, y0 + d)], PATH_BGR, thick)
        polyline([(x0 + d, y0 - c), (x0 - d, y0 + c)], PATH_BGR, thick)
        polyline(path_points(s["x"][:k + 1], s["y"][:k + 1]), PATH_BGR, max(1, thick - 1))
    if track.p_d is not None:
        if track.alpha_d is None:  # the fixed point where the robot is to stop
            cx, cy = x0 + track.p_d * np.cos(a0), y0 + track.p_d * np.sin(a0)
        else:  # where p reaches p_d on the present heading
            go = track.p_d - s["distance"][k]
            cx, cy = x + go * np.cos(a), y + go * np.sin(a)
        q = np.linspace(0, 2 * np.pi, 25)
        polyline(np.column_stack([cx + RING_M * np.cos(q), cy + RING_M * np.sin(q)]), TARGET_BGR, thick)
    if track.alpha_d is not None:
        d = track.alpha_d
        a0, a1 = scene.floor_points([(x, y), (x + HEADING_ARROW_M * np.cos(d), y + HEADING_ARROW_M * np.sin(d))])
        line(a0, a1, TARGET_BGR, thick, arrow=True)
    if drawn_at:
        # the pixels the markers changed, looked for only around them (a whole-picture
        # comparison costs 5 ms a frame)
        pts = np.array(drawn_at)
        m = 2 * thick + 2  # px: a line's half width, its anti-aliasing and an arrow's head
        c0, r0 = np.maximum(np.floor(pts.min(axis=0)).astype(int) - m, 0)
        c1, r1 = np.minimum(np.ceil(pts.max(axis=0)).astype(int) + m + 1, (img.shape[1], img.shape[0]))
        if c1 > c0 and r1 > r0:
            layer, under = img[r0:r1, c0:c1], picture[r0:r1, c0:c1]
            rows, cols = np.nonzero(cv2.cvtColor(cv2.absdiff(layer, under), cv2.COLOR_BGR2GRAY))
            # what the picture shows at those pixels: the floor, or the robot standing in front
            seen = scene.unproject(rows + r0, cols + c0)
            far = np.linalg.norm(seen - scene.eye(), axis=1)
            keep = scene.above_floor(seen) < FLOOR_TOLERANCE + FLOOR_TOLERANCE_PER_M * far
            under[rows[keep], cols[keep]] = layer[rows[keep], cols[keep]]
    img = picture
    if "theta_est" in s:
        ahead = track.r * (s["psi_est"][k] - s["psi"][k])  # m, the estimate's error in distance travelled
        corners = scene.body_points(box_corners(track.box), s["theta_est"][k], s["alpha_est"][k],
                                    x + ahead * np.cos(a), y + ahead * np.sin(a), roll)
        draw_ghost(img, scene.project(corners), 1)
    f = np.array([s["push_fx"][k], s["push_fy"][k], s["push_fz"][k]])
    if np.abs(f).sum() > 0.0:
        top = scene.body_points([(0.0, 0.0, track.body_top)], s["theta"][k], a, x, y, roll)[0]
        line(top - PUSH_M_PER_N * f, top, PUSH_BGR, thick + 1, arrow=True)


def path_points(x, y) -> np.ndarray:
    """(k, 2) m: the path through the points ``x``, ``y`` (m), thinned to points
    :data:`PATH_STEP_M` apart along it (at most :data:`PATH_POINTS`; the last kept): a frame
    draws the path since the start, so its cost must not grow with the frames before it."""
    xy = np.column_stack([np.asarray(x, dtype=float), np.asarray(y, dtype=float)])
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) < 3:
        return xy
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    step = max(PATH_STEP_M, arc[-1] / PATH_POINTS)
    _, first = np.unique(np.floor(arc / step), return_index=True)
    return xy[np.union1d(first, [len(xy) - 1])]


def from_start(track, s: dict, k: int) -> float:
    """m: how far the robot's axle is from where it started, at frame ``k`` of samples ``s``."""
    x0, y0, _ = track.start
    return float(np.hypot(s["x"][k] - x0, s["y"][k] - y0))


def _send(out, payload) -> None:
    """One message: ``payload`` (bytes, or a frame's buffer) with its length in bytes first."""
    out.write(memoryview(payload).nbytes.to_bytes(8, "little"))
    out.write(payload)


def _read_exact(stream, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = stream.read(n - len(buf))
        if not chunk:
            raise EOFError
        buf += chunk
    return bytes(buf)


def _worker_main() -> None:
    """A worker process's whole life (``python -m twin.render.panels``): read its job, a
    pickle, from stdin; render one panel's frames into the protocol stream. The stream is
    the process's original stdout; fd 1 itself is pointed at stderr first, so that what
    PyBullet or EGL print cannot end up inside a frame."""
    import os
    import pickle
    import sys

    subprocess_worker_init()  # first: it goes with a killed parent at once, not at its next frame's write
    out = os.fdopen(os.dup(1), "wb", buffering=1 << 20)
    os.dup2(2, 1)
    try:
        job = pickle.load(sys.stdin.buffer)
        with Scene(job["config"], job["size"], job["renderer"], job["camera"]) as scene:
            _send(out, scene.renderer.encode())
            for panel in panel_frames(scene, job["track"], job["samples"], job["times"], job["hud"]):
                _send(out, panel.data)
    except BaseException as exc:  # the parent turns it into a TwinError
        line = (str(exc).splitlines() or [""])[0]
        try:
            _send(out, _ERROR + f"{type(exc).__name__}: {line}".encode())
        except OSError:
            pass
    finally:
        try:
            out.close()
        except OSError:
            pass


class RemotePanel:
    """A panel rendered by a worker process (``python -m twin.render.panels``, not
    multiprocessing: that would re-import the caller's main module, which a script without
    an ``if __name__ == "__main__"`` guard cannot survive): :meth:`frames` yields its
    pictures as they arrive; :attr:`renderer` is the worker's renderer once the first has.
    Close it (or use ``with``) to stop the worker."""

    def __init__(self, index: int, config, size, renderer, camera, track, samples, times, hud):
        import pickle
        import subprocess
        import sys

        self.index = index
        self.width, self.height = size
        self.n = len(times)
        self.wait = 0.0  # s this process waited for the worker's frames
        self.renderer = ""  # the worker's first message: read with the frames, so workers start together

        self._proc = subprocess.Popen([sys.executable, "-m", "twin.render.panels"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                      env=subprocess_env())  # it dies with this process (twin.workers)
        job = dict(config=config, size=size, renderer=renderer, camera=camera, track=track, samples=samples,
                   times=times, hud=hud)
        try:
            self._proc.stdin.write(pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL))
            self._proc.stdin.close()
        except OSError:
            pass  # the worker died at once: its missing first message says so

    def _message(self) -> bytes:
        t0 = time.perf_counter()
        stream = self._proc.stdout
        try:
            size = int.from_bytes(_read_exact(stream, 8), "little")
            msg = _read_exact(stream, size)
        except EOFError:
            self._proc.wait(5.0)
            raise TwinError(f"the renderer process of video panel {self.index + 1} ended without a word "
                            f"(exit status {self._proc.returncode})") from None
        finally:
            self.wait += time.perf_counter() - t0
        if msg.startswith(_ERROR):
            raise TwinError(f"video panel {self.index + 1}: {msg[len(_ERROR):].decode(errors='replace')}")
        return msg

    def frames(self) -> Iterator[np.ndarray]:
        shape = (self.height, self.width, 3)
        self.renderer = self._message().decode()
        for _ in range(self.n):
            msg = self._message()
            if len(msg) != shape[0] * shape[1] * 3:
                raise TwinError(f"video panel {self.index + 1}: a frame of {len(msg)} bytes, expected "
                                f"{shape[0] * shape[1] * 3}")
            yield np.frombuffer(msg, np.uint8).reshape(shape)

    def close(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.stdout.close()
        self._proc.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


if __name__ == "__main__":
    _worker_main()
