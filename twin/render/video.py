"""MP4 video of logged twin runs, rendered offscreen with PyBullet, encoded as H.264 by ffmpeg.

A replay, decoupled from the simulation: each run's logged ground truth is played back
in a :class:`~twin.render.scene.Scene` of its own (a separate PyBullet world that is
never stepped), so rendering can neither change the physics nor its determinism.

Timing
    Real time: one simulated second is one second of video. At ``fps`` frames per
    second, frame k shows t_k = k / fps (s from each run's start) for
    k = 0 … floor(T · fps), T the longest run's duration: ``floor(T · fps) + 1`` frames
    (61 for a 2 s run at 30 fps). Each run's log (control rate) is interpolated
    linearly at t_k; a run shorter than T (one that fell early) holds its last frame.
    With ``slow = (until, factor)`` the first ``until`` s play ``factor`` times slower
    (frames every 1 / (fps · factor) s of the run, captioned "slow motion"), then real
    time: ``twin run`` slows a catch from a tilted start 4× (its 12 frames at real time
    were the headline event).

Layout
    One panel (``size``) per run, side by side from left to right in the order given,
    each with its own camera following its own robot and its own heads-up overlay
    (:mod:`twin.render.hud`).

Encoding
    H.264 (``avc1``: yuv420p, ``+faststart``; plays in every browser, Safari included)
    by the ffmpeg binary that the ``imageio-ffmpeg`` package bundles, run as a
    subprocess fed raw BGR frames on its stdin: encoder ``libx264`` (preset
    ``ultrafast``, CRF 23), else ``libopenh264`` where that ffmpeg lacks libx264.
    Without a working ffmpeg (package missing, binary absent or failing, no H.264
    encoder in it) OpenCV's ``cv2.VideoWriter`` writes ``vp09`` (VP9), else ``mp4v``
    (MPEG-4 part 2); :attr:`VideoInfo.codec` and :attr:`VideoInfo.encoder` say which
    and :attr:`VideoInfo.note` why H.264 was not used. ``$IMAGEIO_FFMPEG_EXE`` names
    another ffmpeg binary (imageio-ffmpeg's own rule). The file is written under a
    temporary name in the same directory and renamed when complete, so a failed render
    leaves no partial video behind; an ffmpeg that exits with an error raises
    :class:`~twin.errors.TwinError` with its last line of stderr.
"""
from __future__ import annotations

import functools
import math
import os
import queue
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twin.errors import TwinError
from twin.plant.bullet import quiet_native_output
from twin.plant.urdf import body_box
from twin.registry import label as kind_label
from twin.render.hud import plant_caption
from twin.render.panels import panel_frames, RemotePanel
from twin.render.scene import Camera, Scene, check_size, resolve_renderer
from twin.sensors.faults import fault_windows
from twin.sim.bullet_loop import TRUTH_NAMES, TwinRun
from twin.sim.runs import ESTIMATE_NAMES

CODECS = ("avc1", "vp09", "mp4v")  # tried in this order: H.264 by ffmpeg, then OpenCV's VP9 and MPEG-4
H264_ENCODERS = ("libx264", "libopenh264")  # ffmpeg's H.264 encoders, preferred first
X264_ARGS = ("-preset", "ultrafast", "-crf", "23")  # ultrafast: ~3 ms per 1280x480 frame; CRF 23 is x264's default
OPENH264_BITS_PER_PIXEL = 0.15  # libopenh264 has no CRF: a bit rate per pixel and frame instead
MAX_FPS = 240.0
MAX_WIDTH = 7680  # px, the whole side-by-side frame
SEPARATOR = (40, 40, 40)  # BGR line between panels
_TRACK = ("theta", "alpha", "x", "y", "psi_l", "psi_r", "roll", "distance", "psi")
_GHOST = ("theta", "psi", "alpha")  # the estimates the ghost is posed with


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`render_video` wrote.

    Attributes
    ----------
    path : Path
        The MP4 file.
    frames : int
        Frames written.
    size : (width, height) px
        Of the whole frame (panels side by side).
    fps : float
        Frames per second (real time: 1 s of video = 1 s simulated).
    codec : str
        FourCC of the video's codec: ``"avc1"`` (H.264), ``"vp09"`` or ``"mp4v"``.
    renderer : str
        ``"egl"`` or ``"tiny"`` (``"egl+tiny"`` if the panels' scenes differ).
    panels : int
        Runs shown side by side.
    seconds : float
        Wall time spent in :func:`render_video`, s.
    render_seconds : float
        Of which taking the pictures (with the overlay), s.
    encode_seconds : float
        Time the encoder spent on the frames, s. It runs in a thread of its own,
        overlapping the rendering, so ``render_seconds + encode_seconds`` may exceed
        ``seconds``. With ffmpeg, the time spent handing frames to its pipe (blocked
        while it is busy) and waiting for it to finish.
    encoder : str
        What wrote the video: ``"ffmpeg libx264"``, ``"ffmpeg libopenh264"`` or
        ``"opencv vp09"``, ``"opencv mp4v"``.
    note : str
        Why H.264 by ffmpeg was not used (one line); empty when it was.
    """

    path: Path
    frames: int
    size: tuple[int, int]
    fps: float
    codec: str
    renderer: str
    panels: int
    seconds: float
    render_seconds: float
    encode_seconds: float
    encoder: str = ""
    note: str = ""

    @property
    def duration(self) -> float:
        """Length of the video, s."""
        return self.frames / self.fps


def frame_count(duration: float, fps: float) -> int:
    """Frames of a video of runs lasting ``duration`` s at ``fps``: floor(duration · fps) + 1."""
    return int(math.floor(duration * fps + 1e-9)) + 1


def frame_times(duration: float, fps: float, slow=None) -> np.ndarray:
    """Times (s from the start) of the frames: k / fps for k = 0 … floor(duration · fps); with
    ``slow = (until, factor)``, k / (fps · factor) below ``until`` s, then ``until`` + k / fps."""
    if slow is None:
        return np.arange(frame_count(duration, fps)) / float(fps)
    until, factor = min(float(slow[0]), duration), float(slow[1])
    rate = float(fps) * factor
    first = np.arange(int(math.ceil(until * rate - 1e-9))) / rate  # below `until`
    return np.concatenate([first, until + np.arange(frame_count(duration - until, fps)) / float(fps)])


class _Track:
    """A run's log, sampled at frame times (clamped to the run: its last state is held)."""

    def __init__(self, run, label: str):
        self.t = np.asarray(run.t, dtype=float)
        self.duration = float(self.t[-1] - self.t[0])
        self.cols = {name: np.asarray(run.truth[:, TRUTH_NAMES.index(name)], dtype=float) for name in _TRACK}
        e = run.experiment
        self.p_d = None if e is None else e.p_d
        self.alpha_d = None if e is None else e.alpha_d
        self.label = label
        self.plant = plant_caption(getattr(run, "plant", "twin"))  # "" for the PyBullet twin
        self.status = run.status
        self.push = np.asarray(run.push, dtype=float)  # (n, 3) N, world frame
        self.start = (float(self.cols["x"][0]), float(self.cols["y"][0]), float(self.cols["alpha"][0]))
        self.box = None  # the body box's lowest and highest corners, m, body frame
        if run.config is not None:
            self.box = body_box(run.config.params, run.config.body)
            self.r = run.config.params.r
        self.body_top = self.box[1][2] if self.box is not None else 0.2  # m above the axle
        # the estimator's θ, ψ, α, for the ghost (none with ideal sensing: it would be the body)
        self.est = {}
        if run.sensing != "ideal" and run.estimates is not None and self.box is not None:
            self.est = {f"{n}_est": np.asarray(run.estimates[:, ESTIMATE_NAMES.index(f"{n}_est")], dtype=float)
                        for n in _GHOST}
        self.faults = fault_windows(getattr(run.sensor_config, "faults", ()))

    def sample(self, times: np.ndarray) -> dict[str, np.ndarray]:
        tt = self.t[0] + np.minimum(times, self.duration)
        out = {name: np.interp(tt, self.t, col) for name, col in {**self.cols, **self.est}.items()}
        # a push is a pulse of a few control periods: the row in force at each frame, not a blend
        rows = np.clip(np.searchsorted(self.t, tt, side="right") - 1, 0, len(self.t) - 1)
        for i, name in enumerate(("push_fx", "push_fy", "push_fz")):
            out[name] = np.where(times <= self.duration + 1e-9, self.push[rows, i], 0.0)
        return out

    def fault_at(self, t: float) -> str:
        """The names of the sensor faults acting at ``t`` s, for the overlay ("" for none)."""
        return ", ".join(name for name, a, b in self.faults if a - 1e-9 <= t < b - 1e-9)

    def ended(self, t: float) -> str:
        """The overlay's last line at frame time ``t``: empty while the run goes on."""
        if t < self.duration - 1e-9:
            return ""
        if self.status != "ok":
            return f"{self.status.upper()} at {self.duration:.2f} s"
        return f"run ended at {self.duration:.2f} s" if t > self.duration + 1e-9 else ""


def _check_runs(runs) -> list:
    if isinstance(runs, TwinRun):
        runs = [runs]
    elif isinstance(runs, (str, bytes)) or not isinstance(runs, Sequence):
        raise TwinError(f"runs must be a TwinRun or a sequence of TwinRun, got {type(runs).__name__}")
    runs = list(runs)
    if not runs:
        raise TwinError("runs is empty: give a TwinRun or a sequence of at least one")
    for i, r in enumerate(runs):
        if not isinstance(r, TwinRun):
            raise TwinError(f"runs[{i}] must be a TwinRun (from twin.sim.bullet_loop.simulate_twin), "
                            f"got {type(r).__name__}")
        t, truth = np.asarray(r.t, dtype=float), np.asarray(r.truth, dtype=float)
        n = len(t)
        if n < 1 or t.ndim != 1 or truth.shape != (n, len(TRUTH_NAMES)):
            raise TwinError(f"runs[{i}] must log at least one row: t (n,) and truth (n, {len(TRUTH_NAMES)}), "
                            f"got t {t.shape} and truth {truth.shape}")
        cols = [TRUTH_NAMES.index(name) for name in _TRACK]
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(truth[:, cols])) and np.all(np.diff(t) >= 0)):
            raise TwinError(f"runs[{i}] must have finite logged states at non-decreasing times t")
    return runs


def check_fps(fps) -> float:
    """``fps`` as a float if it is a frame rate in [1, MAX_FPS] frames/s; else a one-line TwinError."""
    if not (isinstance(fps, (int, float, np.integer, np.floating)) and not isinstance(fps, bool)
            and math.isfinite(fps) and 1.0 <= fps <= MAX_FPS):
        raise TwinError(f"fps must be a number of frames per second in [1, {MAX_FPS:g}], got {fps!r}")
    return float(fps)


def check_video_path(path) -> Path:
    """``path`` as a Path if it names an .mp4 file whose directory can be made (made here);
    else a one-line TwinError."""
    try:
        p = Path(os.fspath(path))
    except TypeError:
        raise TwinError(f"path must be a file path ending in .mp4, got {path!r}") from None
    if p.suffix.lower() != ".mp4":
        raise TwinError(f"path must end in .mp4 (the video is an MP4 file), got {str(p)!r}")
    if p.is_dir():
        raise TwinError(f"path {str(p)!r} is a directory; give a file name ending in .mp4")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise TwinError(f"cannot write the video {str(p)!r}: cannot make its directory "
                        f"({exc.strerror or exc})") from None
    return p


def _temp_file(p: Path) -> Path:
    """An empty file beside ``p`` to write into (proves the directory writable)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=".partial.mp4", dir=p.parent)
    except OSError as exc:
        raise TwinError(f"cannot write the video {str(p)!r}: {exc.strerror or exc}") from None
    os.close(fd)
    return Path(tmp)


def _publish(tmp: Path, path: Path, encoder_name: str) -> None:
    """Rename the finished ``tmp`` (from :func:`_temp_file`) to ``path``, with an ordinary
    file's permissions; an empty one is an error (the encoder wrote nothing)."""
    if tmp.stat().st_size == 0:
        raise TwinError(f"{encoder_name} wrote nothing to {str(path)!r}; the video is missing")
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp made it private; the video is an ordinary output file
    os.replace(tmp, path)


def _last_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else "no message"


def _ffmpeg_exe() -> str:
    """imageio-ffmpeg's ffmpeg binary (or ``$IMAGEIO_FFMPEG_EXE``); TwinError saying why not."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise TwinError("the package imageio-ffmpeg is not installed") from None
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as exc:
        raise TwinError(f"imageio-ffmpeg found no ffmpeg binary ({_last_line(str(exc))})") from None


@functools.lru_cache(maxsize=8)
def _h264_encoder(exe: str) -> str:
    """The first of :data:`H264_ENCODERS` that the ffmpeg ``exe`` has; TwinError saying why none.
    Cached per binary: listing the encoders takes a process start (~50 ms)."""
    try:
        out = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        raise TwinError(f"ffmpeg {exe!r} does not run ({exc.__class__.__name__}: {exc})") from None
    if out.returncode != 0:
        raise TwinError(f"ffmpeg {exe!r} -encoders exited with status {out.returncode}: "
                        f"{_last_line(out.stderr)}")
    names = {parts[1] for parts in (ln.split() for ln in out.stdout.splitlines()) if len(parts) > 1}
    for enc in H264_ENCODERS:
        if enc in names:
            return enc
    raise TwinError(f"ffmpeg {exe!r} has no H.264 encoder ({' or '.join(H264_ENCODERS)})")


class _FfmpegWriter:
    """An H.264 MP4 written by an ffmpeg subprocess; the ``write``/``release`` interface of
    ``cv2.VideoWriter``, but failures raise TwinError (with ffmpeg's last stderr line)
    instead of passing silently."""

    def __init__(self, exe: str, encoder: str, path: Path, fps: float, size: tuple[int, int]):
        w, h = size
        if w % 2 or h % 2:  # yuv420p subsamples chroma 2x2: odd sizes are refused by the encoders
            raise TwinError(f"H.264 (yuv420p) needs an even frame size, got {w}x{h}")
        self.size = (w, h)
        if encoder == "libx264":
            codec_args = ["-c:v", "libx264", *X264_ARGS]
        else:
            codec_args = ["-c:v", encoder, "-b:v", str(int(OPENH264_BITS_PER_PIXEL * w * h * fps))]
        args = [exe, "-hide_banner", "-loglevel", "error", "-y",  # -y: the temporary file already exists
                "-f", "rawvideo", "-pix_fmt", "bgr24", "-s", f"{w}x{h}", "-framerate", repr(float(fps)), "-i", "-",
                "-an", *codec_args, "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4", str(path)]
        # stderr to a file, not a pipe: an undrained pipe could fill and stall ffmpeg
        self._stderr = tempfile.TemporaryFile()
        try:
            # a session of its own: a Ctrl-C at the terminal reaches this process alone, which
            # then ends ffmpeg itself (kill()), instead of racing ffmpeg's own exit into an
            # "ffmpeg failed" error; if this process dies, ffmpeg reads EOF and exits too
            self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                          stderr=self._stderr, start_new_session=True)
        except OSError as exc:
            self._stderr.close()
            raise TwinError(f"ffmpeg {exe!r} does not start ({exc.strerror or exc})") from None

    def _failure(self, what: str) -> TwinError:
        self._stderr.seek(0)
        last = _last_line(self._stderr.read().decode("utf-8", "replace"))
        return TwinError(f"ffmpeg failed {what} (exit status {self._proc.returncode}): {last}")

    def write(self, frame: np.ndarray) -> None:
        """Hand a BGR frame (h, w, 3) uint8 to ffmpeg; blocks while its pipe is full."""
        if frame.shape != (self.size[1], self.size[0], 3) or frame.dtype != np.uint8:
            raise TwinError(f"a frame must be {self.size[1]}x{self.size[0]}x3 uint8, got {frame.shape} {frame.dtype}")
        try:
            self._proc.stdin.write(memoryview(np.ascontiguousarray(frame)).cast("B"))
        except (BrokenPipeError, ValueError):  # ffmpeg has exited (ValueError: pipe already closed)
            self._finish()
            raise self._failure("while encoding") from None

    def _finish(self) -> int:
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            try:
                self._proc.stdin.close()  # end of input: ffmpeg flushes and writes the moov atom
            except BrokenPipeError:
                pass
        return self._proc.wait()

    def kill(self) -> None:
        """End ffmpeg now (the video is being abandoned: nothing it would still encode is wanted)."""
        if self._proc.poll() is None:
            self._proc.kill()

    def release(self) -> None:
        """Close the input, wait for ffmpeg; TwinError if it exited with an error."""
        try:
            if self._finish() != 0:
                raise self._failure("writing the video")
        finally:
            self._stderr.close()


def _open_opencv(path: Path, fps: float, size: tuple[int, int]):
    """A ``cv2.VideoWriter`` open on ``path`` with OpenCV's first codec of :data:`CODECS` that works."""
    import cv2

    for fourcc in CODECS[1:]:
        with quiet_native_output():  # FFmpeg logs each codec it cannot open
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, size)
        if writer.isOpened():
            return writer, fourcc
        writer.release()
    raise TwinError(f"OpenCV cannot write an MP4 video here with any of the codecs {', '.join(CODECS[1:])} "
                    f"(cv2 {cv2.__version__}), and H.264 by ffmpeg is not available either; "
                    f"pip install imageio-ffmpeg")


def _open_writer(path: Path, fps: float, size: tuple[int, int]):
    """The writer of the first codec of :data:`CODECS` that works here: ``(writer, codec,
    encoder, note)``; ``note`` says why H.264 by ffmpeg was not used ("" when it was)."""
    try:
        exe = _ffmpeg_exe()
        encoder = _h264_encoder(exe)
        return _FfmpegWriter(exe, encoder, path, fps, size), "avc1", f"ffmpeg {encoder}", ""
    except TwinError as exc:
        why = str(exc)
    writer, fourcc = _open_opencv(path, fps, size)
    return writer, fourcc, f"opencv {fourcc}", f"video encoded by OpenCV as {fourcc}, not H.264: {why}"


class _Encoder:
    """Feeds a writer (``cv2.VideoWriter`` or :class:`_FfmpegWriter`) from a thread of its
    own, so that encoding (OpenCV's encoders release the GIL; ffmpeg is a process of its
    own and a pipe write releases it too) overlaps the rendering of later frames."""

    def __init__(self, writer, depth: int = 6):
        self.writer = writer
        self.busy = 0.0  # s spent in writer.write and writer.release
        self.error: BaseException | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._thread = threading.Thread(target=self._run, name="twin-video-encoder", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            frame = self._queue.get()
            if frame is None:
                return
            if self.error is None:
                t0 = time.perf_counter()
                try:
                    self.writer.write(frame)
                except BaseException as exc:  # handed to the rendering thread at its next put
                    self.error = exc
                self.busy += time.perf_counter() - t0

    def put(self, frame: np.ndarray) -> None:
        """Queue a BGR frame (not to be changed afterwards); waits while the queue is full."""
        if self.error is not None:
            raise self.error
        self._queue.put(frame)

    def abort(self) -> None:
        """Abandon the video (an error or an interrupt): end ffmpeg first, so that neither the
        frames queued nor those in its pipe are encoded, then stop the thread; errors are
        not raised (the one that stopped the video is)."""
        kill = getattr(self.writer, "kill", None)
        if kill is not None:
            kill()
        try:
            self.close()
        except BaseException:  # noqa: BLE001 -- a broken pipe, or the killed ffmpeg's exit status
            pass

    def close(self) -> None:
        """Encode what is queued, then release the writer (also after an error)."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        t0 = time.perf_counter()
        self.writer.release()
        self.busy += time.perf_counter() - t0
        if self.error is not None:
            raise self.error


class VideoStream:
    """An MP4 written frame by frame while it is rendered: H.264 by ffmpeg where it can be (else
    OpenCV's first codec that works, :data:`CODECS`), encoded on a thread of its own, under a
    temporary name beside ``path`` until :meth:`close` renames it into place; :meth:`abort`
    (an error, an interrupt) leaves no file. The frame size is the first frame's.

    Parameters
    ----------
    path : str or Path
        The video, ending in ``.mp4`` (:func:`check_video_path`).
    fps : float
        Frames per second (:func:`check_fps`).

    After :meth:`close`: ``frames``, ``size`` (w, h) px, ``codec`` ("avc1", or OpenCV's
    fourcc), ``encoder`` ("ffmpeg libx264", …), ``note`` (why not H.264 by ffmpeg; "" when
    it was) and ``encode_seconds`` (s spent encoding).
    """

    def __init__(self, path, fps: float):
        self.fps = check_fps(fps)
        self.path = check_video_path(path)
        self._tmp = _temp_file(self.path)  # made now: a directory that cannot take it is said at once
        self._encoder: _Encoder | None = None
        self.frames = 0
        self.size: tuple[int, int] | None = None
        self.codec = self.encoder = self.note = ""
        self.encode_seconds = 0.0

    def put(self, frame: np.ndarray) -> None:
        """Queue a BGR frame, (h, w, 3) uint8, not to be changed afterwards (waits while the
        encoder's queue is full)."""
        if self._encoder is None:
            if self._tmp is None:
                raise TwinError(f"the video {str(self.path)!r} is closed")
            self.size = (frame.shape[1], frame.shape[0])
            writer, self.codec, self.encoder, self.note = _open_writer(self._tmp, self.fps, self.size)
            self._encoder = _Encoder(writer)
        self._encoder.put(frame)
        self.frames += 1

    def close(self) -> bool:
        """Encode what is queued and put the video in its place; False (and no file) if no
        frame was put."""
        enc, self._encoder = self._encoder, None
        tmp, self._tmp = self._tmp, None
        if tmp is None:
            return False
        if enc is None:
            tmp.unlink(missing_ok=True)
            return False
        try:
            enc.close()
            _publish(tmp, self.path, self.encoder)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        finally:
            self.encode_seconds = enc.busy
        return True

    def abort(self) -> None:
        """Abandon the video: nothing more is encoded and no file is left."""
        enc, self._encoder = self._encoder, None
        tmp, self._tmp = self._tmp, None
        if enc is not None:
            enc.abort()
        if tmp is not None:
            tmp.unlink(missing_ok=True)


def _default_label(run, i: int) -> str:
    """The run's name as the figure and metrics.json give it (the registry's label: "IT2", "type-1",
    "LQR", a plugin's attribute), then the experiment's."""
    label = kind_label(run.controller) if run.controller else f"run {i + 1}"
    if run.experiment is not None and run.experiment.name:
        label += f"  {run.experiment.name}"
    return label


def _caption(frame: np.ndarray, text: str, w: int, panels: int) -> None:
    """``text`` at the bottom centre of each of ``panels`` panels (w px wide) of ``frame``, white on
    a dark band (in place)."""
    import cv2

    scale = max(0.4, frame.shape[0] / 900.0)
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    for j in range(panels):
        x, y = j * w + (w - tw) // 2, frame.shape[0] - 10
        frame[y - th - 6:y + base + 2, x - 6:x + tw + 6] //= 3
        cv2.putText(frame, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)


def render_video(runs, path, fps: float = 30, size=(640, 480),
                 progress: Callable[[int, int], object] | None = None, *, renderer: str | None = None,
                 camera: Camera | None = None, labels: Sequence[str] | None = None, hud: bool = True,
                 parallel: bool | None = None, slow=None) -> VideoInfo:
    """Render logged twin runs into an MP4 video, side by side, in real time.

    Parameters
    ----------
    runs : TwinRun or sequence of TwinRun
        What to show (from :func:`twin.sim.bullet_loop.simulate_twin`), one panel each, left
        to right.
    path : str or PathLike
        The video file; must end in ``.mp4``. Its directory is made if missing; an
        existing file is replaced once the new video is complete.
    fps : float
        Frames per second, in [1, 240]. Frames are taken at k / fps s (see the module
        docstring): floor(T · fps) + 1 frames for runs lasting T s at most.
    size : (width, height) px
        Of each panel: even integers from 32x24 to 3840x2160; the video is
        (len(runs) · width) x height, at most 7680 px wide.
    progress : callable, optional
        Called as ``progress(frames_done, frames_total)`` after each frame is rendered
        (the encoder trails by a few frames; the call returns once all are written).
    renderer : {"auto", "egl", "tiny"}, optional
        PyBullet's EGL plugin or its TinyRenderer; default ``$TWIN_RENDERER`` or
        ``"auto"`` (EGL where it loads). See :mod:`twin.render.scene`.
    camera : Camera, optional
        Where the panels' cameras sit relative to their robots.
    labels : sequence of str, optional
        One per run, shown at the top of its overlay; default the controller's label
        (upper case) and the experiment's name.
    hud : bool
        Draw the heads-up overlay (time s, pitch rad, distance m, heading rad, targets; the
        plant when it is not the PyBullet twin: ``Run.plant``).
    parallel : bool, optional
        Render each panel in a worker process of its own (:mod:`twin.render.panels`)
        while this one composes and encodes; default: when there are several runs and
        more than one CPU. The frames are the same either way.
    slow : (until s, factor), optional
        Play the first ``until`` s ``factor`` (1–16) times slower, captioned (see the module
        docstring); None: real time throughout.

    Returns
    -------
    VideoInfo
        Frames, size, fps, codec, encoder (and why not H.264), renderer and the time spent.

    Raises
    ------
    TwinError
        Bad input (no runs, fps or size out of range, a path that is not a writable
        ``.mp4`` file), no working MP4 encoder, or ffmpeg exiting with an error (its
        last stderr line); the message says what is allowed or what went wrong.
    """
    t_start = time.perf_counter()
    runs = _check_runs(runs)
    fps = check_fps(fps)
    w, h = check_size(size)
    total_w = w * len(runs)
    if total_w > MAX_WIDTH:
        raise TwinError(f"{len(runs)} panels of {w} px make the video {total_w} px wide; at most {MAX_WIDTH} px "
                        f"are allowed: give fewer runs or a smaller size")
    if labels is None:
        labels = [_default_label(r, i) for i, r in enumerate(runs)]
    elif (isinstance(labels, (str, bytes)) or not isinstance(labels, Sequence) or len(labels) != len(runs)
          or not all(isinstance(s, str) for s in labels)):
        raise TwinError(f"labels must be a sequence of {len(runs)} strings, one per run, got {labels!r}")
    if progress is not None and not callable(progress):
        raise TwinError(f"progress must be a callable progress(frames_done, frames_total) or None, got {progress!r}")
    if parallel is not None and not isinstance(parallel, bool):
        raise TwinError(f"parallel must be True, False or None (automatic), got {parallel!r}")
    if slow is not None and not (isinstance(slow, (tuple, list)) and len(slow) == 2
                                 and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                         for v in slow) and slow[0] > 0.0 and 1.0 <= slow[1] <= 16.0):
        raise TwinError(f"slow must be (until s > 0, factor in [1, 16]) or None, got {slow!r}")
    if camera is not None and not isinstance(camera, Camera):
        raise TwinError(f"camera must be a twin.render.Camera, got {camera!r}")
    renderer = resolve_renderer(renderer)
    path = check_video_path(path)

    tracks = [_Track(r, labels[i]) for i, r in enumerate(runs)]
    times = frame_times(max(tr.duration for tr in tracks), fps, slow)
    n = len(times)
    slow_frames = 0 if slow is None else int(np.sum(times < float(slow[0]) - 1e-12))
    caption = None if slow is None else f"slow motion: 1/{float(slow[1]):g} speed"
    samples = [tr.sample(times) for tr in tracks]
    if parallel is None:
        parallel = len(runs) > 1 and (os.cpu_count() or 1) > 1
    stream = VideoStream(path, fps)
    scenes: list[Scene] = []
    remotes: list[RemotePanel] = []
    t_render = 0.0
    try:
        sources = []
        for j, (r, tr, smp) in enumerate(zip(runs, tracks, samples)):
            if parallel:
                remotes.append(RemotePanel(j, r.config, (w, h), renderer, camera, tr, smp, times, hud))
                sources.append(remotes[-1].frames())
            else:
                scenes.append(Scene(r.config, (w, h), renderer, camera))
                sources.append(panel_frames(scenes[-1], tr, smp, times, hud))
        for k in range(n):
            t0 = time.perf_counter()
            panels = [next(src) for src in sources]
            if len(panels) == 1:
                frame = panels[0]
            else:
                frame = np.hstack(panels)
                for j in range(1, len(panels)):
                    frame[:, j * w - 1:j * w + 1] = SEPARATOR
            if k < slow_frames:  # the slowed frames say so, at the bottom of each panel
                _caption(frame, caption, w, len(panels))
            t_render += time.perf_counter() - t0
            stream.put(frame)
            if progress is not None:
                progress(k + 1, n)
        stream.close()
    except BaseException:
        stream.abort()
        raise
    finally:
        for scene in scenes:
            scene.close()
        for remote in remotes:
            remote.close()
    used = sorted({s.renderer for s in scenes} | {rp.renderer for rp in remotes})
    return VideoInfo(path=path, frames=n, size=(total_w, h), fps=fps, codec=stream.codec, renderer="+".join(used),
                     panels=len(runs), seconds=time.perf_counter() - t_start, render_seconds=t_render,
                     encode_seconds=stream.encode_seconds, encoder=stream.encoder, note=stream.note)
