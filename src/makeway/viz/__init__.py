"""Visual output: annotated frames and H.264 video files."""

from makeway.viz.annotate import PALETTE, STATE_COLOURS, draw_frame, track_colour
from makeway.viz.video_writer import (
    DEFAULT_PRESET,
    DEFAULT_X264_PARAMS,
    H264Writer,
    partial_path_for,
    pick_h264_encoder,
)

__all__ = [
    "DEFAULT_PRESET",
    "DEFAULT_X264_PARAMS",
    "PALETTE",
    "STATE_COLOURS",
    "H264Writer",
    "draw_frame",
    "partial_path_for",
    "pick_h264_encoder",
    "track_colour",
]
