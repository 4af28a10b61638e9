"""One robot on its floor in a PyBullet world of its own, posed from a log and photographed.

The scene is a replay: nothing is ever stepped. Each frame the robot's body is put where
the twin had it: oriented R = Rz(α) Rx(φ) Ry(θ) from the logged heading, roll and pitch
(the twin's own decomposition, :func:`twin.plant.bullet.truth_from_states`), its axle
midpoint at the logged (x, y) and at the height where both wheels stand on the floor
(:func:`twin.plant.bullet.initial_pose`, as the twin spawns it); the wheel joints at the
logged wheel angles relative to the body, q_i = ψ_i − θ. The twin's readout of the
posed robot gives back the logged θ, φ, α, x, y, ψ_l, ψ_r. Then ``getCameraImage``
takes the picture. The physics of a run is never touched: the scene
has its own DIRECT ``BulletClient`` (never the global pybullet connection).

Renderers
    ``"egl"``: PyBullet's EGL renderer plugin (OpenGL; hardware where a GPU driver is
    present, Mesa's llvmpipe in software otherwise). ``"tiny"``: PyBullet's built-in
    TinyRenderer (CPU, always there, slower). ``"auto"`` (default) uses EGL where it
    works and TinyRenderer otherwise. The environment variable ``TWIN_RENDERER``
    (``auto``, ``egl`` or ``tiny``) sets the default.

    Whether EGL works is found out once per process, in a child process
    (:func:`egl_available`): where libEGL is missing or cannot initialise, PyBullet's
    plugin ends the whole process (``exit(1)``) instead of failing the load, so it is
    loaded here only once a child has loaded it and drawn a picture with it.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass, replace

import numpy as np

from twin.errors import TwinError
from twin.params import NOMINAL
from twin.interrupts import deferred_signals
from twin.plant.base import TwinConfig, initial_pose
from twin.plant.bullet import WHEEL_JOINTS, client_id, disconnect, quiet_native_output
from twin.plant.urdf import UNIT_CUBE_OBJ, body_box, robot_urdf
from twin.rotations import body_quaternion, matrix_rows

RENDERERS = ("auto", "egl", "tiny")
RENDERER_ENV = "TWIN_RENDERER"
MIN_SIZE = (32, 24)  # px, smallest frame (width, height)
MAX_SIZE = (3840, 2160)  # px, largest frame of one panel
# Towards the light, world frame. The EGL plugin puts a point light at this position (m)
# and TinyRenderer a directional light along it: both light the floor and the side the
# default cameras see, and cast the robot's shadow away from them.
_LIGHT_DIRECTION = (0.6, -1.0, 2.0)
_FAR_AWAY = (0.0, 0.0, -1000.0)  # where a hidden robot goes: far below the floor


_EGL_PROBE = r"""
import os, pkgutil, sys
import numpy, pybullet, pybullet_data
from pybullet_utils.bullet_client import BulletClient
c = BulletClient(connection_mode=pybullet.DIRECT)
loader = pkgutil.get_loader("eglRenderer")
plugin = c.loadPlugin(loader.get_filename(), "_eglRendererPlugin") if loader is not None else -1
if plugin < 0:
    sys.exit(3)
c.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"))
view = c.computeViewMatrixFromYawPitchRoll((0, 0, 0), 2.0, 0.0, -30.0, 0.0, 2)
proj = c.computeProjectionMatrixFOV(45.0, 4 / 3, 0.01, 60.0)
rgba = c.getCameraImage(32, 24, view, proj, renderer=pybullet.ER_BULLET_HARDWARE_OPENGL)[2]
img = numpy.asarray(rgba, dtype=numpy.uint8).reshape(24, 32, 4)[:, :, :3]
c.unloadPlugin(plugin)
c.disconnect()
print("TWIN_EGL_DRAWS" if img.max() > img.min() else "TWIN_EGL_BLANK")
"""
_egl_lock = threading.Lock()
_egl_works: bool | None = None
EGL_PROBE_TIMEOUT = 60.0  # s


def egl_available() -> bool:
    """Whether PyBullet's EGL renderer plugin loads and draws here (asked once per process).

    A child Python loads the plugin and renders a small picture of the floor; True if it
    exits cleanly with a picture that is not blank. Never loads the plugin in this process.
    """
    global _egl_works
    with _egl_lock:
        if _egl_works is None:
            try:
                done = subprocess.run([sys.executable, "-c", _EGL_PROBE], stdin=subprocess.DEVNULL,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                      timeout=EGL_PROBE_TIMEOUT, check=False)
                _egl_works = done.returncode == 0 and b"TWIN_EGL_DRAWS" in done.stdout
            except (OSError, ValueError, subprocess.SubprocessError):
                _egl_works = False
        return _egl_works


def resolve_renderer(renderer: str | None = None) -> str:
    """The renderer asked for: ``renderer``, else ``$TWIN_RENDERER``, else ``"auto"``.

    Raises :class:`TwinError` if it is not one of :data:`RENDERERS`.
    """
    source = "renderer"
    if renderer is None:
        renderer = os.environ.get(RENDERER_ENV, "").strip() or "auto"
        source = RENDERER_ENV
    if not isinstance(renderer, str) or renderer.lower() not in RENDERERS:
        raise TwinError(f"{source} must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    return renderer.lower()


def check_size(size, what: str = "size") -> tuple[int, int]:
    """``size`` as (width, height) ints, or :class:`TwinError` naming the allowed range."""
    try:
        w, h = size
        ok = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (w, h))
    except (TypeError, ValueError):
        ok = False
    if ok:
        w, h = int(w), int(h)
        ok = (MIN_SIZE[0] <= w <= MAX_SIZE[0] and MIN_SIZE[1] <= h <= MAX_SIZE[1] and w % 2 == 0 and h % 2 == 0)
    if not ok:
        raise TwinError(f"{what} must be (width, height) in pixels, even integers from {MIN_SIZE[0]}x{MIN_SIZE[1]} "
                        f"to {MAX_SIZE[0]}x{MAX_SIZE[1]}, got {size!r}")
    return w, h


@dataclass(frozen=True)
class Camera:
    """A camera that follows the robot.

    Parameters
    ----------
    distance : m
        From the target point to the eye.
    yaw : deg
        Azimuth of the view. With ``follow_heading`` it is relative to the robot's
        heading: 0 looks at the robot's right side with its forward direction to the
        right of the picture (a side view: pitch reads best); positive swings the eye
        round towards the robot's front (90: head-on). Without, it is relative to the
        world (0: the eye on the −y side, world +x to the right of the picture).
    pitch : deg
        Elevation of the view, negative looking down.
    fov : deg
        Vertical field of view.
    target_height : m
        The camera aims this far above the axle midpoint (world vertical), so that the
        body sits in the middle of the picture.
    follow_heading : bool
        Turn with the robot's heading (True) or keep a fixed world direction.
    aim : (x, y, z) m, optional
        A fixed world point to aim at instead of the robot (a camera that does not move);
        ``target_height`` is added to z.
    swing : (t_start s, t_end s, yaw_end deg), optional
        The bearing turns from ``yaw`` to ``yaw_end`` between the two times, smoothly (a
        smoothstep): a side view of a catch from a tilted start that then turns to see the
        run's travel and turning.
    """

    distance: float = 0.85
    yaw: float = 25.0
    pitch: float = -12.0
    fov: float = 45.0
    target_height: float = 0.06
    follow_heading: bool = True
    aim: tuple | None = None
    swing: tuple | None = None

    def __post_init__(self):
        for name, lo, hi in (("distance", 0.05, 100.0), ("yaw", -360.0, 360.0), ("pitch", -89.0, 89.0),
                             ("fov", 5.0, 150.0), ("target_height", -10.0, 10.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and lo <= v <= hi):
                raise TwinError(f"camera {name} must be a number in [{lo:g}, {hi:g}], got {v!r}")
        if not isinstance(self.follow_heading, bool):
            raise TwinError(f"camera follow_heading must be True or False, got {self.follow_heading!r}")
        if self.aim is not None:
            ok = (isinstance(self.aim, (tuple, list)) and len(self.aim) == 3
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          for v in self.aim))
            if not ok:
                raise TwinError(f"camera aim must be a world point (x, y, z) in m, or None, got {self.aim!r}")
            object.__setattr__(self, "aim", tuple(float(v) for v in self.aim))
        if self.swing is not None:
            ok = (isinstance(self.swing, (tuple, list)) and len(self.swing) == 3
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          for v in self.swing) and 0.0 <= self.swing[0] < self.swing[1]
                  and -360.0 <= self.swing[2] <= 360.0)
            if not ok:
                raise TwinError(f"camera swing must be (t_start s, t_end s, yaw_end deg) with 0 <= t_start < t_end "
                                f"and yaw_end in [-360, 360], or None, got {self.swing!r}")
            object.__setattr__(self, "swing", tuple(float(v) for v in self.swing))

    def yaw_at(self, t: float | None = None) -> float:
        """The bearing (deg) at time ``t`` s (None: the start's): ``yaw``, turning to the swing's
        ``yaw_end`` between its two times."""
        if self.swing is None or t is None:
            return self.yaw
        t0, t1, end = self.swing
        u = min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        return self.yaw + (end - self.yaw) * u * u * (3.0 - 2.0 * u)


CAMERA_MODES = ("follow", "turning", "fixed", "top")


SWING_S = 1.5  # s: how long the follow camera takes to turn from the catch's side view to the run's bearing


def robot_scale(params, body=None) -> float:
    """The robot's height (wheel radius and the body box's top) over the paper robot's: 1 for the
    paper's robot, exactly; what the cameras scale their distance and aim by, so that a robot of
    any size fills the picture as the paper's does."""
    def height(p, box):
        return p.r + body_box(p, box)[1][2]

    return height(params, body) / height(NOMINAL, None)


def camera_mode(mode: str, alpha0: float = 0.0, extent=None, alpha_d: float | None = None,
                catch_end: float | None = None, scale: float = 1.0) -> Camera:
    """The camera of ``video.camera`` = ``mode`` for a run starting at heading ``alpha0`` rad
    whose axle stays inside ``extent`` = (x_min, x_max, y_min, y_max) m (for "fixed"), with
    the heading target ``alpha_d`` rad (None: none).

    * ``follow``: follows the robot at a bearing fixed in the world (the side view of its
      starting heading, or with a heading target of the heading halfway to it, so that
      the start and the end are seen equally from the side and the target's arrow is not
      hidden behind the body), so that its turning shows as the robot turning and its
      travel as the floor moving under it; the default. With a heading target and a catch
      from a tilted start that ends at ``catch_end`` s, the camera first sees the catch from
      the side of the starting heading (halfway to a 1.5 rad target it saw the pitch nearly
      end-on) and turns to the halfway bearing over :data:`SWING_S` s after it.
    * ``turning``: follows the robot and turns with its heading (a side view throughout).
    * ``fixed``: does not move: aims at the middle of ``extent`` from far enough back to
      see all of it, from the starting side, looking down 25°.
    * ``top``: follows the robot from above, its starting heading to the right.
    """
    camera = _camera_mode(mode, alpha0, extent, alpha_d, catch_end)
    if scale == 1.0:
        return camera
    # another robot's size: the same picture of it (the fixed camera stands back by the extent already)
    distance = camera.distance if mode == "fixed" else max(0.05, camera.distance * scale)
    return replace(camera, distance=distance, target_height=camera.target_height * scale)


def _camera_mode(mode, alpha0, extent, alpha_d, catch_end) -> Camera:
    side = 25.0 + math.degrees(alpha0)  # the turning camera's bearing at the start
    if mode == "follow":
        middle = alpha0 if alpha_d is None else 0.5 * (alpha0 + alpha_d)
        if catch_end is not None and alpha_d is not None:
            return Camera(yaw=25.0 + math.degrees(alpha0), follow_heading=False,
                          swing=(catch_end, catch_end + SWING_S, 25.0 + math.degrees(middle)))
        return Camera(yaw=25.0 + math.degrees(middle), follow_heading=False)
    if mode == "turning":
        return Camera()
    if mode == "top":
        return Camera(distance=1.6, yaw=math.degrees(alpha0), pitch=-89.0, follow_heading=False)
    if mode == "fixed":
        x0, x1, y0, y1 = extent if extent is not None else (0.0, 0.0, 0.0, 0.0)
        span = math.hypot(x1 - x0, y1 - y0)
        return Camera(distance=max(0.85, 1.3 * span + 0.6), yaw=side, pitch=-25.0, follow_heading=False,
                      aim=(0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0))
    raise TwinError(f"video camera must be one of {', '.join(CAMERA_MODES)}, got {mode!r}")


_EGL_OPEN: set = set()  # ids of the open scenes that loaded the EGL plugin
_EGL_PARKED: list = []  # (client, plugin) of EGL scenes closed while others were open


def _release(client, plugin: int) -> None:
    """Unload ``plugin`` (if ≥ 0) and disconnect ``client`` (if still connected)."""
    if client_id(client) < 0:
        return
    with quiet_native_output():
        try:
            if plugin >= 0:
                client.unloadPlugin(plugin)
        finally:
            disconnect(client)


class Scene:
    """The robot of a :class:`~twin.plant.bullet.TwinConfig` on its floor, for pictures.

    Parameters
    ----------
    config : TwinConfig
        The run's configuration: robot parameters (body and wheel geometry), payload,
        centre-of-mass offset and the floor's slope.
    size : (width, height) px
        Size of the pictures.
    renderer : {"auto", "egl", "tiny"} or None
        See the module docstring; None reads ``$TWIN_RENDERER`` (default ``"auto"``).
        ``"egl"`` raises :class:`TwinError` if the plugin does not work here.
    camera : Camera, optional

    Attributes
    ----------
    renderer : str
        ``"egl"`` or ``"tiny"``: the renderer in use.

    Use as a context manager, or call :meth:`close`, to free the PyBullet server.
    """

    def __init__(self, config: TwinConfig, size=(640, 480), renderer: str | None = None,
                 camera: Camera | None = None):
        if not isinstance(config, TwinConfig):
            raise TwinError(f"config must be a TwinConfig, got {type(config).__name__}")
        camera = Camera() if camera is None else camera
        if not isinstance(camera, Camera):
            raise TwinError(f"camera must be a twin.render.Camera, got {camera!r}")
        self.width, self.height = check_size(size)
        requested = resolve_renderer(renderer)
        self.camera = camera
        self.config = config
        self.client = None
        self._plugin = -1
        # signals held: an interrupt raised before BulletClient stored its server's id left a
        # client whose __del__ printed a traceback after the command's line (see twin.plant.bullet._connect)
        with deferred_signals(), quiet_native_output():
            import pybullet
            import pybullet_data
            from pybullet_utils.bullet_client import BulletClient

            self._pb = pybullet
            self.client = c = BulletClient(connection_mode=pybullet.DIRECT)
        try:
            if requested in ("auto", "egl"):
                self._plugin = self._load_egl() if egl_available() else -1
                if self._plugin < 0 and requested == "egl":
                    raise TwinError("the EGL renderer plugin does not work here (no usable libEGL?); use renderer "
                                    f"'tiny' or 'auto' (or set {RENDERER_ENV}=tiny)")
            p, g, d = config.params, config.ground, config.disturbances
            plane_q = (0.0, 0.0, 0.0, 1.0)
            if g.slope != 0.0:  # as BulletTwin: the floor rises towards slope_direction
                axis = (-math.sin(g.slope_direction), math.cos(g.slope_direction), 0.0)
                h = -0.5 * g.slope
                plane_q = (axis[0] * math.sin(h), axis[1] * math.sin(h), 0.0, math.cos(h))
            self.plane = c.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), (0.0, 0.0, 0.0),
                                    plane_q, useFixedBase=True)
            with tempfile.TemporaryDirectory(prefix="mtwip-render-") as tmp:
                cube = os.path.join(tmp, "unit_cube.obj")
                with open(cube, "w") as f:
                    f.write(UNIT_CUBE_OBJ)
                path = os.path.join(tmp, "robot.urdf")
                with open(path, "w") as f:
                    f.write(robot_urdf(p, d.payload, d.com_offset, box_mesh=cube, body=self.config.body))
                self.robot = c.loadURDF(path, _FAR_AWAY, (0.0, 0.0, 0.0, 1.0), useFixedBase=True)
            # PyBullet's base position is the body's centre of mass (its inertial frame)
            self._com_local = np.array((d.com_offset[0], d.com_offset[1], p.l + d.com_offset[2]))
            self._proj = c.computeProjectionMatrixFOV(camera.fov, self.width / self.height, 0.01, 60.0)
            self.renderer = "egl" if self._plugin >= 0 else "tiny"
            if self._plugin >= 0:
                _EGL_OPEN.add(id(self))
        except BaseException:
            self.close()
            raise
        self._flags = pybullet.ER_NO_SEGMENTATION_MASK
        self._mode = pybullet.ER_BULLET_HARDWARE_OPENGL if self.renderer == "egl" else pybullet.ER_TINY_RENDERER

    # ---- lifecycle ---------------------------------------------------------------------
    def _load_egl(self) -> int:
        import pkgutil

        try:
            loader = pkgutil.get_loader("eglRenderer")
            filename = loader.get_filename() if loader is not None else None
        except Exception:  # pragma: no cover - a broken install
            filename = None
        if not filename:
            return -1
        with quiet_native_output():
            try:
                return int(self.client.loadPlugin(filename, "_eglRendererPlugin"))
            except Exception:  # pragma: no cover - pybullet raises only on a bad call
                return -1

    def close(self) -> None:
        """Unload the EGL plugin and disconnect the PyBullet server (idempotent).

        PyBullet's EGL plugin tears down process-wide state when a client that loaded it
        unloads it or disconnects: another EGL scene still open then crashes on its next
        picture. So an EGL scene closed while others are open is only parked, and the
        parked clients are released with the last EGL scene."""
        client = self.client
        if client is None:
            return
        self.client = None
        if self._plugin >= 0:
            _EGL_OPEN.discard(id(self))
            if _EGL_OPEN:
                _EGL_PARKED.append((client, self._plugin))
                self._plugin = -1
                return
        plugin, self._plugin = self._plugin, -1
        try:
            _release(client, plugin)
        finally:
            while _EGL_PARKED and not _EGL_OPEN:
                _release(*_EGL_PARKED.pop())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    # ---- posing and pictures ---------------------------------------------------------------
    def pose(self, theta: float, alpha: float, x: float, y: float, psi_l: float, psi_r: float,
             roll: float = 0.0):
        """Put the robot as the twin had it; returns the axle midpoint (m, world).

        ``theta`` pitch (rad, positive leaning forward), ``alpha`` heading (rad), (x, y)
        axle midpoint (m), ``psi_l``, ``psi_r`` wheel angles from the vertical (rad),
        ``roll`` (rad) as the twin logs them (:class:`~twin.plant.bullet.GroundTruth`).
        """
        c = self._require_open()
        axle, _ = initial_pose(self.config.params, self.config.ground, theta, alpha, x, y)
        q = body_quaternion(theta, alpha, roll)
        com = np.asarray(axle) + np.array(matrix_rows(q)) @ self._com_local
        c.resetBasePositionAndOrientation(self.robot, com.tolist(), q)
        c.resetJointState(self.robot, WHEEL_JOINTS[0], psi_l - theta, 0.0)
        c.resetJointState(self.robot, WHEEL_JOINTS[1], psi_r - theta, 0.0)
        return axle

    def body_points(self, points, theta: float, alpha: float, x: float, y: float, roll: float = 0.0) -> np.ndarray:
        """World coordinates (k, 3) m of ``points`` (k, 3) m given in the body frame (origin
        the axle midpoint, x forward, z up the body) with the robot posed as :meth:`pose`
        would pose it (pitch ``theta``, heading ``alpha``, roll ``roll`` rad, axle above
        (``x``, ``y``) m on the floor)."""
        axle, _ = initial_pose(self.config.params, self.config.ground, theta, alpha, x, y)
        R = np.array(matrix_rows(body_quaternion(theta, alpha, roll)))
        return np.asarray(axle) + np.atleast_2d(np.asarray(points, dtype=float)) @ R.T

    def floor_points(self, xy, lift: float = 0.002) -> np.ndarray:
        """World points (k, 3) m on the floor (sloped or not) at ``xy`` (k, 2) m, raised
        ``lift`` m so that a marker drawn there is not taken for a floor tile's edge."""
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        g = self.config.ground
        z = [g.height(float(px), float(py)) + lift for px, py in xy]
        return np.column_stack([xy, z])

    def hide_robot(self) -> None:
        """Move the robot out of sight (far below the floor)."""
        self._require_open().resetBasePositionAndOrientation(self.robot, _FAR_AWAY, (0.0, 0.0, 0.0, 1.0))

    def view_matrix(self, target, alpha: float = 0.0, t: float | None = None):
        """The camera's view matrix aiming at ``target`` (m, world), the robot heading ``alpha`` rad,
        at time ``t`` s (a swinging camera's bearing; None: its start's)."""
        cam = self.camera
        yaw = cam.yaw_at(t) + (math.degrees(alpha) if cam.follow_heading else 0.0)
        if cam.aim is not None:  # a camera that does not move
            target = cam.aim
        aim = (float(target[0]), float(target[1]), float(target[2]) + cam.target_height)
        return self._require_open().computeViewMatrixFromYawPitchRoll(aim, cam.distance, yaw, cam.pitch, 0.0, 2)

    def picture(self, target, alpha: float = 0.0, t: float | None = None) -> np.ndarray:
        """RGB picture (height, width, 3) uint8 of the scene as it stands, camera on ``target`` at time
        ``t`` s (see :meth:`view_matrix`)."""
        c = self._require_open()
        view = self.view_matrix(target, alpha, t)
        self._last_view = view
        with quiet_native_output():  # the EGL plugin prints its GL vendor on the first pictures
            _, _, rgba, depth, _ = c.getCameraImage(self.width, self.height, view, self._proj, shadow=1,
                                                    lightDirection=_LIGHT_DIRECTION, renderer=self._mode,
                                                    flags=self._flags)
        self._last_depth = depth  # OpenGL window depth in [0, 1], (height, width); read by unproject
        return np.asarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)[:, :, :3]

    def unproject(self, rows, cols) -> np.ndarray:
        """World points (k, 3) m that the last picture shows at the pixels (``rows``,
        ``cols``) (k,): where the ray through each pixel's centre meets the first surface
        drawn there (the sky gives points on the far plane)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        d = np.asarray(self._last_depth, dtype=float).reshape(self.height, self.width)[rows, cols]
        V = np.asarray(self._last_view, dtype=float).reshape(4, 4).T
        P = np.asarray(self._proj, dtype=float).reshape(4, 4).T
        ndc = np.column_stack([2.0 * (cols + 0.5) / self.width - 1.0, 1.0 - 2.0 * (rows + 0.5) / self.height,
                               2.0 * d - 1.0, np.ones(len(d))])
        w = np.linalg.solve(P @ V, ndc.T).T
        return w[:, :3] / w[:, 3:4]

    def eye(self) -> np.ndarray:
        """Where the camera of the last picture was (3,) m, world."""
        V = np.asarray(self._last_view, dtype=float).reshape(4, 4).T
        return -V[:3, :3].T @ V[:3, 3]

    def above_floor(self, points) -> np.ndarray:
        """Height (k,) m of world ``points`` (k, 3) above the floor's plane, along its normal."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        g = self.config.ground
        n = np.asarray(g.normal())
        return pts @ n  # the floor's plane passes through the origin

    def project(self, points) -> np.ndarray:
        """Pixel coordinates (k, 2) (column, row) of world points ``points`` (k, 3) m in the
        last picture taken; NaN for a point behind the camera."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        V = np.asarray(self._last_view, dtype=float).reshape(4, 4).T  # PyBullet's matrices are column-major
        P = np.asarray(self._proj, dtype=float).reshape(4, 4).T
        clip = (P @ V @ np.column_stack([pts, np.ones(len(pts))]).T).T
        w = clip[:, 3]
        out = np.full((len(pts), 2), np.nan)
        ok = w > 1e-9
        out[ok, 0] = (clip[ok, 0] / w[ok] + 1.0) * 0.5 * self.width
        out[ok, 1] = (1.0 - clip[ok, 1] / w[ok]) * 0.5 * self.height
        return out

    def render(self, theta: float, alpha: float, x: float, y: float, psi_l: float, psi_r: float,
               roll: float = 0.0, show_robot: bool = True, t: float | None = None) -> np.ndarray:
        """Pose the robot (see :meth:`pose`) and return its RGB picture (height, width, 3) uint8,
        at time ``t`` s (a swinging camera's bearing, see :class:`Camera`).

        ``show_robot=False`` takes the same picture with the robot out of sight.
        """
        axle = self.pose(theta, alpha, x, y, psi_l, psi_r, roll)
        if not show_robot:
            self.hide_robot()
        return self.picture(axle, alpha, t)

    def _require_open(self):
        if self.client is None:
            raise TwinError("the scene is closed; make a new one")
        return self.client
