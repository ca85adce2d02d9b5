"""Draw what the vision stages concluded onto a video frame (OpenCV drawing only).

Each track gets its box, coloured by its EV state (:data:`STATE_COLOURS`; a stable per-id colour
from :data:`PALETTE` when it has no state), and a label bar ``#id label score`` plus, when the
smoother has judged it, ``ev <positive fraction>``. An active EV is drawn with a thick red outline
and a white ``EV`` tag, on top of everything else. A semi-transparent panel in the top-left corner
shows the frame index, time, track count, active-EV count and optional extra lines.

Only the panel's own rectangle is alpha-blended; everything else is plain line/rectangle/text
drawing, so a 720p frame with a dozen tracks costs well under a millisecond or two. Sizes scale with
the frame height (reference: 720 px).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from makeway.messages import EVState, EVTrackState, PerceptionFrame, Track

Colour = tuple[int, int, int]

#: Box colours by EV state, BGR: active = bright red, inactive = green, warming up = amber.
STATE_COLOURS: dict[EVState, Colour] = {
    EVState.ACTIVE: (0, 0, 255),
    EVState.INACTIVE: (0, 200, 0),
    EVState.WARMING_UP: (0, 191, 255),
}

#: Colours for tracks without an EV state, BGR; none of them close to red, green or amber.
PALETTE: tuple[Colour, ...] = (
    (255, 144, 30),  # dodger blue
    (255, 255, 0),  # cyan
    (255, 0, 255),  # magenta
    (211, 0, 148),  # dark violet
    (230, 216, 173),  # light blue
    (128, 128, 0),  # teal
    (255, 191, 0),  # deep sky blue
    (219, 112, 147),  # medium purple
    (238, 130, 238),  # violet
    (205, 90, 106),  # slate blue
    (208, 224, 64),  # turquoise
    (235, 235, 235),  # near white
)

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_WHITE: Colour = (255, 255, 255)
_BLACK: Colour = (0, 0, 0)
_PANEL_DARKEN = 0.35  # panel background keeps this share of the video underneath


def track_colour(track_id: int) -> Colour:
    """A colour from :data:`PALETTE` that depends only on ``track_id`` (neighbouring ids differ)."""
    return PALETTE[(int(track_id) * 7) % len(PALETTE)]


def _text_colour(background: Colour) -> Colour:
    b, g, r = background
    return _BLACK if 0.114 * b + 0.587 * g + 0.299 * r > 140 else _WHITE


class _Style:
    """Font sizes and line widths scaled to the frame height."""

    def __init__(self, height: int) -> None:
        s = min(max(height / 720.0, 0.6), 3.0)
        self.font_scale = 0.55 * s
        self.text_thick = max(1, round(1.2 * s))
        self.tag_thick = self.text_thick + 1 if s >= 0.9 else self.text_thick
        self.box_thick = max(1, round(2 * s))
        self.active_thick = max(3, round(5 * s))
        self.pad = max(2, round(4 * s))
        (_, th), baseline = cv2.getTextSize("Ag#0", _FONT, self.font_scale, self.text_thick)
        self.text_h = th
        self.baseline = baseline
        self.line_h = th + baseline + 2 * self.pad


def _label_text(track: Track, state: EVTrackState | None) -> str:
    text = f"#{track.track_id} {track.label} {track.score:.2f}"
    if state is not None:
        text += f"  ev {state.positive_fraction:.2f}"
    return text


def _draw_tag(
    img: np.ndarray, x: int, y_top: int, text: str, bg: Colour, fg: Colour, style: _Style, thick: int
) -> int:
    """A filled label ``text`` with its top-left at ``(x, y_top)``; returns its right edge."""
    (tw, _), _ = cv2.getTextSize(text, _FONT, style.font_scale, thick)
    x2 = x + tw + 2 * style.pad
    cv2.rectangle(img, (x, y_top), (x2, y_top + style.line_h), bg, cv2.FILLED)
    baseline_y = y_top + style.pad + style.text_h
    cv2.putText(img, text, (x + style.pad, baseline_y), _FONT, style.font_scale, fg, thick, cv2.LINE_AA)
    return x2


def _draw_track(img: np.ndarray, track: Track, state: EVTrackState | None, style: _Style) -> None:
    h, w = img.shape[:2]
    b = track.box
    coords = (b.x1, b.y1, b.x2, b.y2)
    if not all(math.isfinite(v) for v in coords):
        return
    x1 = int(round(min(max(b.x1, 0.0), w - 1)))
    y1 = int(round(min(max(b.y1, 0.0), h - 1)))
    x2 = int(round(min(max(b.x2, 0.0), w - 1)))
    y2 = int(round(min(max(b.y2, 0.0), h - 1)))
    if x2 <= x1 or y2 <= y1:
        return
    active = state is not None and state.state is EVState.ACTIVE
    colour = STATE_COLOURS[state.state] if state is not None else track_colour(track.track_id)
    cv2.rectangle(img, (x1, y1), (x2, y2), colour, style.active_thick if active else style.box_thick)

    # Label bar above the box, or just inside its top edge when there is no room above.
    y_top = y1 - style.line_h if y1 - style.line_h >= 0 else y1
    x = x1
    if active:
        x = _draw_tag(img, x, y_top, "EV", _WHITE, STATE_COLOURS[EVState.ACTIVE], style, style.tag_thick)
    _draw_tag(img, x, y_top, _label_text(track, state), colour, _text_colour(colour), style, style.text_thick)


def _draw_panel(img: np.ndarray, lines: Sequence[tuple[str, Colour]], style: _Style) -> None:
    h, w = img.shape[:2]
    width = max(cv2.getTextSize(t, _FONT, style.font_scale, style.text_thick)[0][0] for t, _ in lines)
    margin = style.pad
    px2 = min(w, margin + width + 4 * style.pad)
    py2 = min(h, margin + len(lines) * (style.text_h + style.baseline + style.pad) + 2 * style.pad)
    if px2 <= margin or py2 <= margin:
        return
    roi = img[margin:py2, margin:px2]
    cv2.convertScaleAbs(roi, dst=roi, alpha=_PANEL_DARKEN)
    y = margin + style.pad
    for text, colour in lines:
        y += style.text_h + style.pad
        cv2.putText(
            img,
            text,
            (margin + 2 * style.pad, y),
            _FONT,
            style.font_scale,
            colour,
            style.text_thick,
            cv2.LINE_AA,
        )
        y += style.baseline


def draw_frame(
    frame_bgr: np.ndarray,
    frame: PerceptionFrame,
    *,
    fps_text: str | None = None,
    extra_lines: Sequence[str] = (),
    copy: bool = True,
) -> np.ndarray:
    """Draw the tracks, EV states and an info panel of ``frame`` onto ``frame_bgr``.

    Args:
        frame_bgr: the video frame, ``H × W × 3`` BGR ``uint8``.
        frame: what perception concluded for this frame.
        fps_text: shown as a line of the panel (for example ``"42.0 fps"``) when given.
        extra_lines: further panel lines.
        copy: draw on a copy and leave ``frame_bgr`` untouched (default); ``False`` draws in place
            (``frame_bgr`` must then be C-contiguous and writable) and saves one frame copy.

    Returns:
        The annotated image (``frame_bgr`` itself when ``copy=False``).
    """
    if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3 or frame_bgr.dtype != np.uint8:
        raise ValueError(f"frame_bgr must be an H×W×3 uint8 image, got {frame_bgr.dtype} {frame_bgr.shape}")
    img = frame_bgr.copy() if copy else frame_bgr
    style = _Style(img.shape[0])
    states = {s.track_id: s for s in frame.ev_states}

    # Active EVs last, so that they are drawn over everything else.
    def order(t: Track) -> int:
        s = states.get(t.track_id)
        return 1 if s is not None and s.state is EVState.ACTIVE else 0

    for track in sorted(frame.tracks, key=order):
        _draw_track(img, track, states.get(track.track_id), style)

    n_active = sum(1 for t in frame.tracks if order(t))
    lines: list[tuple[str, Colour]] = [
        (f"frame {frame.frame_index}   t {frame.time_s:.2f} s", _WHITE),
        (f"tracks {len(frame.tracks)}   active EV {n_active}", (80, 80, 255) if n_active else _WHITE),
    ]
    if fps_text:
        lines.append((fps_text, _WHITE))
    lines.extend((str(line), _WHITE) for line in extra_lines)
    _draw_panel(img, lines, style)
    return img
