"""Sensor input: video files, MOTChallenge files, crop folders and YOLO sets, microphone-array
recordings and their calibration, camera models and the vehicle's camera rig.

* :class:`VideoReader` — frames of a video file with their timestamps (:mod:`~makeway.sense.video`);
* :func:`read_recording` — an array recording folder (audio, geometry, logged trajectories);
* :mod:`~makeway.sense.camera` — pinhole and Kannala–Brandt fisheye intrinsics (pixel ↔ ray);
  :mod:`~makeway.sense.rig` — the rig file, pixel → vehicle-frame ray and azimuth;
  :mod:`~makeway.sense.camera_calibration` — intrinsics from chessboard images;
* :mod:`~makeway.sense.motfile`, :mod:`~makeway.sense.crops`, :mod:`~makeway.sense.calibration`.
"""

from makeway.sense.recording import Recording, read_recording, recording_folders
from makeway.sense.video import DEFAULT_FPS, VideoInfo, VideoReader, probe_video

__all__ = [
    "DEFAULT_FPS",
    "Recording",
    "VideoInfo",
    "VideoReader",
    "probe_video",
    "read_recording",
    "recording_folders",
]
