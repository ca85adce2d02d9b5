"""The picture of ``makeway audio listen``: a spectrogram of channel 0 (0–4 kHz) with the siren
windows shaded (the strip on top coloured by approaching/receding), and a polar plot of the bearing
(and distance, with the networks) track coloured by time; the true nearest siren in grey when the
recording logs its trajectory."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from makeway.perceive.audio.windows import WINDOW_S
from makeway.sense.recording import Recording

__all__ = ["plot_listen"]

PLOT_MAX_HZ = 4000.0


def plot_listen(
    messages: Iterable[dict[str, Any]],
    recording: Recording,
    out_png: str | Path,
    *,
    window_s: float = WINDOW_S,
) -> Path:
    """Spectrogram with the siren windows shaded (the strip on top coloured by approaching/receding),
    and the polar bearing track; written atomically."""
    from matplotlib.figure import Figure

    from makeway.atomic import atomic_path

    msgs = list(messages)
    sr = int(recording.sample_rate)
    x = np.asarray(recording.audio[:, 0], dtype=np.float64)
    nfft, hop = 1024, 512
    n_frames = max(1, 1 + (len(x) - nfft) // hop) if len(x) >= nfft else 0
    fig = Figure(figsize=(12, 4.5), dpi=100, layout="constrained")
    gs = fig.add_gridspec(1, 3)
    ax = fig.add_subplot(gs[0, :2])
    if n_frames:
        frames = np.lib.stride_tricks.sliding_window_view(x, nfft)[::hop][:n_frames]
        spec = np.abs(np.fft.rfft(frames * np.hanning(nfft), axis=1)) ** 2
        f = np.fft.rfftfreq(nfft, 1.0 / sr)
        keep = f <= PLOT_MAX_HZ
        db = 10.0 * np.log10(np.maximum(spec[:, keep].T, 1e-20))
        t_edges = (np.arange(n_frames + 1) * hop + nfft / 2 - hop / 2) / sr
        f_k = f[keep]
        f_edges = np.concatenate([f_k - (f_k[1] - f_k[0]) / 2, [f_k[-1] + (f_k[1] - f_k[0]) / 2]])
        vmax = float(np.max(db))
        ax.pcolormesh(t_edges, f_edges, db, shading="flat", cmap="magma", vmin=vmax - 80.0, vmax=vmax)
    strip = {True: "tab:red", False: "tab:blue", None: "cyan"}  # approaching, receding, undecided
    for m in msgs:
        if m["is_siren"]:
            approaching = m["sources"][0]["approaching"] if m["sources"] else None
            ax.axvspan(m["t_end"] - window_s, m["t_end"], color="cyan", alpha=0.08, lw=0)
            ax.axvspan(m["t_end"] - window_s, m["t_end"], ymin=0.97, color=strip[approaching], lw=0)
    ax.set_xlim(0.0, recording.duration_s)
    ax.set_ylim(0.0, PLOT_MAX_HZ)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("frequency (Hz), channel 0")
    ax.set_title(
        "spectrogram; shaded: siren detected\ntop strip: approaching (red), receding (blue), undecided (cyan)"
    )

    pax: Any = fig.add_subplot(gs[0, 2], projection="polar")  # a PolarAxes
    pax.set_theta_zero_location("N")  # 0 = straight ahead, up; positive = left, counter-clockwise
    ranged = any(s["distance_m"] is not None for m in msgs for s in m["sources"])
    if ranged:  # the network's bearing and distance: a map around the car, truth in grey when logged
        r_max = 100.0
        if recording.sources:
            from makeway.eval.siren_labels import label_recording

            lab = label_recording(recording, window_s=window_s)
            th, dist = lab.nearest()
            pax.plot(th, dist, color="0.6", lw=1.0, label="true nearest siren")
        first = [(m["t_end"], s["bearing_rad"], s["distance_m"]) for m in msgs for s in m["sources"][:1]]
        more = [s["bearing_rad"] for m in msgs for s in m["sources"][1:]]
        if first:
            tt, bb, rr = (np.array(v, dtype=np.float64) for v in zip(*first, strict=True))
            sc = pax.scatter(
                bb, np.minimum(rr, r_max), c=tt, cmap="viridis", s=12, vmin=0.0, vmax=recording.duration_s
            )
            fig.colorbar(sc, ax=pax, label="time (s)", shrink=0.7)
        if more:
            pax.scatter(
                more,
                np.full(len(more), 0.95 * r_max),
                marker="x",
                color="tab:red",
                s=14,
                label="other sirens",
            )
        pax.set_rlim(0.0, r_max)
        pax.set_title("sirens: bearing and distance (m); up = ahead")
        if recording.sources or more:
            pax.legend(loc="lower left", fontsize=7, bbox_to_anchor=(-0.15, -0.15))
    else:
        pts = [(m["t_end"], s["bearing_rad"]) for m in msgs for s in m["sources"]]
        if pts:
            tt, bb = (np.array(v) for v in zip(*pts, strict=True))
            sc = pax.scatter(bb, tt, c=tt, cmap="viridis", s=12, vmin=0.0, vmax=recording.duration_s)
            fig.colorbar(sc, ax=pax, label="time (s)", shrink=0.7)
        pax.set_rlim(0.0, max(recording.duration_s, 1e-3))
        pax.set_title("bearing track (up = ahead, left = left)")
    target = Path(out_png)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png")
    return target
