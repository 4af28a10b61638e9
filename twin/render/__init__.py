"""Offscreen videos of logged twin runs (PyBullet replay, OpenCV overlay, H.264 MP4 by ffmpeg).

>>> from twin.render import render_video
>>> info = render_video([run_it2, run_t1], "runs/exp3/video.mp4")  # doctest: +SKIP
>>> info.frames, info.codec, info.renderer  # doctest: +SKIP
(451, 'avc1', 'egl')

PyBullet and OpenCV are imported when a video is made, not with this package.
"""
from twin.render.hud import HudState, draw_hud
from twin.render.scene import RENDERER_ENV, RENDERERS, Camera, Scene, egl_available, resolve_renderer
from twin.render.video import CODECS, VideoInfo, frame_count, frame_times, render_video

__all__ = ["CODECS", "RENDERERS", "RENDERER_ENV", "Camera", "HudState", "Scene", "VideoInfo", "draw_hud",
           "egl_available", "frame_count", "frame_times", "render_video", "resolve_renderer"]
