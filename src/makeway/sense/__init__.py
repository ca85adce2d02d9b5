"""Sensor input: video files, MOTChallenge files (`sense.motfile`), array recordings (`sense.recording`)."""

from makeway.sense.video import DEFAULT_FPS, VideoInfo, VideoReader, probe_video

__all__ = ["DEFAULT_FPS", "VideoInfo", "VideoReader", "probe_video"]
