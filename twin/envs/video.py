"""Real-time video of mtwip episodes: :class:`RecordVideo`, the twin's counterpart of
``gymnasium.wrappers.RecordVideo``.

Why not Gymnasium's wrapper: it takes one picture per step and writes the video at
``metadata["render_fps"]``. The environments step at the control rate (200 Hz), so
Gymnasium's recorder renders all 3001 states of a 15 s episode (some tens of
milliseconds each at 640x480), keeps the pictures in memory (about 3 GB), needs moviepy
to encode them, and writes a 200 frames/s file. This wrapper renders only the steps that fall on the
video's frame times (30 per simulated second by default) and streams them to the
project's H.264 writer (:mod:`twin.render.video`: the ffmpeg of ``imageio-ffmpeg``, a
dependency of the twin) while the episode runs, so a 15 s episode is 451 pictures
and a 15 s video at 30 frames/s.

Timing
    Frame j shows the state at the first control instant at or after j / fps s
    (at most one control period, 5 ms, later); when the episode ends between two frame
    times, one more frame shows its last state (the heads-up overlay then reads
    ``FELL at …`` or ``END at …``). One simulated second is one second of video.
"""
from __future__ import annotations

import os
import time
from os import PathLike
from pathlib import Path

import gymnasium
import numpy as np

from twin.envs.base import TwinEnv
from twin.errors import TwinError
from twin.render.video import check_fps, check_video_path, frame_count, VideoInfo, VideoStream


def capped_cubic_video_schedule(episode: int) -> bool:
    """Gymnasium's default trigger (``gymnasium.utils.save_video``, which cannot be imported
    without moviepy): episodes k³ below 1000 (0, 1, 8, 27, … 729), then every 1000th."""
    if episode < 1000:
        return int(round(episode ** (1.0 / 3))) ** 3 == episode
    return episode % 1000 == 0


class _Recording:
    """One episode's video being written (:class:`twin.render.video.VideoStream`) and its frame clock."""

    def __init__(self, path: Path, fps: float, rate: float):
        self._frame_count = frame_count  # due() runs every control step: looked up once
        self.path = path
        self.fps = fps
        self.rate = rate  # control steps per simulated second
        self.stream = VideoStream(path, fps)
        self.frames = 0  # frames written; the next one is due at frames / fps s
        self.last_k = -1  # the control step of the last picture taken
        self.render_seconds = 0.0
        self.started = time.perf_counter()

    def put(self, rgb: np.ndarray, k: int) -> None:
        if not (isinstance(rgb, np.ndarray) and rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.dtype == np.uint8):
            raise TwinError(f"render() must return an (H, W, 3) uint8 picture to record, got "
                            f"{getattr(rgb, 'shape', type(rgb).__name__)}")
        self.stream.put(np.ascontiguousarray(rgb[:, :, ::-1]))  # the stream takes BGR
        self.frames += 1
        self.last_k = k

    def due(self, k: int) -> int:
        """Frames due once control step ``k`` (at k / rate s) has been simulated."""
        return max(0, self._frame_count(k / self.rate, self.fps) - self.frames)  # frames at 0, 1/fps, … ≤ k / rate

    def finish(self, renderer: str):
        st = self.stream
        if not st.close():  # nothing was rendered: no video
            return None
        return VideoInfo(path=self.path, frames=self.frames, size=st.size, fps=self.fps, codec=st.codec,
                         renderer=renderer, panels=1, seconds=time.perf_counter() - self.started,
                         render_seconds=self.render_seconds, encode_seconds=st.encode_seconds, encoder=st.encoder,
                         note=st.note)

    def abort(self) -> None:
        self.stream.abort()


class RecordVideo(gymnasium.Wrapper, gymnasium.utils.RecordConstructorArgs):
    """Record episodes of an mtwip environment as real-time H.264 MP4 video (see the module docstring).

    A drop-in for ``gymnasium.wrappers.RecordVideo`` on the twin's environments (same
    ``video_folder``, ``episode_trigger``, ``name_prefix`` and ``fps`` arguments, same file
    names) that needs no moviepy and renders only what the video shows::

        import gymnasium
        from twin.envs import RecordVideo

        env = RecordVideo(gymnasium.make("mtwip/Balance-v0", render_mode="rgb_array"),
                          "videos", episode_trigger=lambda episode: True)

    Each recorded episode becomes ``{video_folder}/{name_prefix}-episode-{k}.mp4`` (k
    counts the resets from 0), written under a temporary name and renamed when the
    episode ends (terminated or truncated), at the next :meth:`reset` or at
    :meth:`close`, whichever comes first; an error or an interrupt while recording
    leaves no partial file. :attr:`videos` lists what was written.

    Parameters
    ----------
    env : gymnasium.Env
        An mtwip environment (:class:`twin.envs.TwinEnv` underneath any wrappers) made
        with ``render_mode="rgb_array"``.
    video_folder : str or path
        Directory of the videos (made if missing; a video of the same name is replaced).
    episode_trigger : callable, optional
        ``episode_trigger(k) -> bool``: record episode k (from 0). Default
        :func:`capped_cubic_video_schedule` (episodes 0, 1, 8, 27, … 729, then every
        1000th), as Gymnasium's RecordVideo; ``lambda k: True`` records every episode.
    name_prefix : str
        Start of the file names.
    fps : float, optional
        Frames per simulated second, in [1, 240]; default the scenario's ``video.fps``
        (:attr:`TwinEnv.video_fps`, 30). Real time at any rate: above the control rate a
        picture is repeated.

    Attributes
    ----------
    videos : list of twin.render.VideoInfo
        One per finished video: path, frames, size (px), fps, codec, encoder, renderer,
        and wall times (``seconds`` from the episode's reset to the file's completion,
        simulation included; ``render_seconds`` taking the pictures; ``encode_seconds``).
    fps : float
        Frames per simulated second.

    Raises
    ------
    TwinError
        The environment is not an mtwip one or has no ``rgb_array`` render mode, or an
        argument is out of range (one line naming it); while recording, a failing encoder.
    """

    def __init__(self, env: gymnasium.Env, video_folder, episode_trigger=None, name_prefix: str = "rl-video",
                 fps: float | None = None):
        gymnasium.utils.RecordConstructorArgs.__init__(self, video_folder=video_folder,
                                                       episode_trigger=episode_trigger, name_prefix=name_prefix,
                                                       fps=fps)
        gymnasium.Wrapper.__init__(self, env)
        raw = env.unwrapped
        if not isinstance(raw, TwinEnv):
            raise TwinError(f"RecordVideo records the mtwip environments (twin.envs.TwinEnv), got "
                            f"{type(raw).__name__}; use gymnasium.wrappers.RecordVideo for others")
        if env.render_mode != "rgb_array":
            raise TwinError(f"RecordVideo needs an environment made with render_mode='rgb_array', got "
                            f"render_mode={env.render_mode!r}")
        if not isinstance(video_folder, (str, PathLike)):
            raise TwinError(f"video_folder must be a directory path, got {video_folder!r}")
        if episode_trigger is None:
            episode_trigger = capped_cubic_video_schedule
        elif not callable(episode_trigger):
            raise TwinError(f"episode_trigger must be a callable episode_trigger(episode) -> bool or None, "
                            f"got {episode_trigger!r}")
        if not isinstance(name_prefix, str) or not name_prefix or os.sep in name_prefix:
            raise TwinError(f"name_prefix must be a non-empty file name prefix (no {os.sep!r}), got {name_prefix!r}")
        self.fps = check_fps(raw.video_fps if fps is None else fps)
        self.video_folder = Path(os.fspath(video_folder))
        self.episode_trigger = episode_trigger
        self.name_prefix = name_prefix
        self.episode_id = -1
        self.videos: list = []
        self._rec: _Recording | None = None

    # ---- the Gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Finish the running video (if any), reset the environment, and start recording the
        new episode if ``episode_trigger`` says so (its first frame: the initial state)."""
        self._finish()
        obs, info = self.env.reset(seed=seed, options=options)
        self.episode_id += 1
        if self.episode_trigger(self.episode_id):
            path = check_video_path(self.video_folder / f"{self.name_prefix}-episode-{self.episode_id}.mp4")
            self._rec = _Recording(path, self.fps, self.unwrapped.control_rate)
            self._guarded(self._capture, 0)
        return obs, info

    def step(self, action):
        """Step the environment; take the pictures of the frame times it passed; finish the
        video when the episode ends."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._rec is not None:
            k = self.unwrapped.loop.k
            self._guarded(self._capture, k)
            if terminated or truncated:
                if self._rec.last_k != k:  # the last state, between two frame times
                    self._guarded(self._picture, k, 1)
                self._finish()
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Finish the running video (the episode so far), then close the environment."""
        try:
            self._finish()
        finally:
            super().close()

    @property
    def recording(self) -> bool:
        """Whether the current episode is being recorded."""
        return self._rec is not None

    # ---- recording -----------------------------------------------------------------------------
    def _guarded(self, fn, *args) -> None:
        try:
            fn(*args)
        except BaseException:
            rec, self._rec = self._rec, None
            if rec is not None:
                rec.abort()
            raise

    def _capture(self, k: int) -> None:
        n = self._rec.due(k)
        if n:
            self._picture(k, n)

    def _picture(self, k: int, n: int) -> None:
        rec = self._rec
        t0 = time.perf_counter()
        frame = self.env.render()
        rec.render_seconds += time.perf_counter() - t0
        for _ in range(n):
            rec.put(frame, k)

    def _finish(self) -> None:
        rec = self._rec
        if rec is None:
            return
        scene = self.unwrapped._scene
        try:
            info = rec.finish(scene.renderer if scene is not None else "")
        except BaseException:
            rec.abort()
            raise
        finally:
            self._rec = None
        if info is not None:
            self.videos.append(info)

    def __del__(self):  # a recorder dropped without close(): no partial file, no ffmpeg left running
        rec = getattr(self, "_rec", None)
        if rec is not None:
            self._rec = None
            try:
                rec.abort()
            except BaseException:  # noqa: BLE001 -- interpreter shutdown
                pass


__all__ = ["RecordVideo", "capped_cubic_video_schedule"]
