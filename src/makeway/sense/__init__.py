"""Sensor input: video files (audio readers join here later)."""

from makeway.sense.video import DEFAULT_FPS, VideoInfo, VideoReader, probe_video

__all__ = ["DEFAULT_FPS", "VideoInfo", "VideoReader", "probe_video"]
