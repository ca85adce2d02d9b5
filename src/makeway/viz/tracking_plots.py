"""Plots of ``makeway demo``'s tracking part: track paths, EV probability over time, smoother sweep."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.scene_tracking import DISPLAY_T, THRESHOLDS, SceneTrackRecord
from makeway.messages import EVState
from makeway.sim.traffic import Scene, SceneRenderer

__all__ = ["plot_ev_probability", "plot_sweep", "plot_tracks"]


def _figure(width_in: float, height_in: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=100, layout="constrained")


_TAB = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2",
    "#7f7f7f", "#bcbd22", "#17becf", "#aec7e8", "#ffbb78", "#98df8a",
)  # fmt: skip
_EV_COLOUR = "#d62728"
#: Per-track colours in the probability plot: none of them red, green, purple or amber (the colours of
#: the states and of the lights-on truth).
_TRACK_COLOURS = ("#1f77b4", "#2f4f4f", "#8c564b", "#e377c2", "#17becf", "#393b79", "#7f7f7f", "#bcbd22")


def plot_tracks(
    path: Path,
    scene: Scene,
    records: list[list[SceneTrackRecord]],
    track_to_actor: dict[int, int | None],
    renderer: SceneRenderer,
) -> None:
    """Ground-truth vs SORT trajectories (box bottom centres) over the empty road."""
    fig = _figure(15, 5.3)
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    bg = renderer.background[::2, ::2, ::-1]
    s = renderer.scale
    extent = (0, renderer.width / s, renderer.height / s, 0)
    gt_paths: dict[int, list[tuple[float, float]]] = defaultdict(list)
    for frame in scene.frames:
        for t in frame.truth:
            if t.considered:
                gt_paths[t.actor_id].append((0.5 * (t.box.x1 + t.box.x2), t.box.y2))
    trk_paths: dict[int, list[tuple[float, float]]] = defaultdict(list)
    for row in records:
        for r in row:
            trk_paths[r.track_id].append((0.5 * (r.box[0] + r.box[2]), r.box[3]))
    ev_set = set(scene.ev_ids)
    ax = axes[0]
    ax.imshow(bg, extent=extent, alpha=0.45)
    for k, (aid, pts) in enumerate(sorted(gt_paths.items())):
        p = np.array(pts)
        ev = aid in ev_set
        ax.plot(p[:, 0], p[:, 1], "-", lw=2.6 if ev else 1.4, color=_EV_COLOUR if ev else _TAB[k % len(_TAB)])
        ax.annotate(
            f"{scene.actors[aid].kind.name} {aid}" if ev else str(aid),
            p[-1],
            fontsize=7,
            color=_EV_COLOUR if ev else "black",
        )
    ax.set_title(f"ground truth: {len(gt_paths)} vehicles (EVs in red)")
    ax = axes[1]
    ax.imshow(bg, extent=extent, alpha=0.45)
    for tid, pts in sorted(trk_paths.items()):
        p = np.array(pts)
        actor = track_to_actor.get(tid)
        ev = actor in ev_set
        colour = _EV_COLOUR if ev else ("black" if actor is None else _TAB[tid % len(_TAB)])
        ax.plot(p[:, 0], p[:, 1], ".-", ms=1.5, lw=2.2 if ev else 1.0, color=colour)
        if len(p) >= 50 or ev:  # label the longer tracks only; the far end is crowded
            ax.annotate(f"#{tid}", p[-1], fontsize=7, color=colour)
    n_unmapped = sum(1 for v in track_to_actor.values() if v is None)
    ax.set_title(f"SORT: {len(trk_paths)} tracks ({n_unmapped} matching no vehicle, in black)")
    for ax in axes:
        ax.set_xlim(0, scene.width)
        ax.set_ylim(scene.height, 0)
        ax.set_xlabel("u (px)")
    axes[0].set_ylabel("v (px), box bottom centre")
    fig.savefig(path)


def _strip(ax: Any, t: np.ndarray, mask: np.ndarray, y0: float, y1: float, colour: str, **kw: Any) -> None:
    ax.fill_between(t, y0, y1, where=mask, step="post", color=colour, lw=0, **kw)


def plot_ev_probability(
    path: Path, scene: Scene, records: list[list[SceneTrackRecord]], metrics: dict[str, Any]
) -> None:
    """Per EV (and the most EV-like ordinary vehicle): raw probability, positive fraction, state."""
    track_to_actor: dict[int, int | None] = metrics["track_to_actor"]
    fps = scene.fps
    by_actor: dict[int, list[SceneTrackRecord]] = defaultdict(list)
    for row in records:
        for r in row:
            a = track_to_actor.get(r.track_id)
            if a is not None:
                by_actor[a].append(r)
    panels = [a for a in scene.ev_ids if a in by_actor]
    ev_set = set(scene.ev_ids)
    decoys = [
        (sum(1 for r in rs if r.probability is not None and r.probability >= 0.5), a)
        for a, rs in by_actor.items()
        if a not in ev_set
    ]
    decoys.sort(reverse=True)
    if decoys and decoys[0][0] > 0:
        panels.append(decoys[0][1])
    fig = _figure(13, 2.9 * max(1, len(panels)) + 0.4)
    axes = fig.subplots(max(1, len(panels)), 1, squeeze=False)[:, 0]
    t_all = np.arange(scene.num_frames + 1) / fps
    if not panels:
        axes[0].text(
            0.5,
            0.5,
            "no emergency vehicle was tracked in this scene",
            ha="center",
            transform=axes[0].transAxes,
        )
    # amber is the truth (lights on); the smoothed states take colours of their own
    state_colour = {EVState.ACTIVE: "#d62728", EVState.INACTIVE: "#2ca02c", EVState.WARMING_UP: "#b39ddb"}
    ev_info = {e["actor_id"]: e for e in metrics["evs"]}
    for ax, a in zip(axes, panels, strict=False):
        actor = scene.actors[a]
        rs = sorted(by_actor[a], key=lambda r: (r.frame, r.track_id))
        # truth: lights-on strip at the bottom, grey background while the vehicle is in view
        lit = np.zeros(scene.num_frames + 1, dtype=bool)
        seen = np.zeros(scene.num_frames + 1, dtype=bool)
        for f in scene.frames:
            tb = next((t for t in f.truth if t.actor_id == a), None)
            if tb is not None:
                lit[f.index] = tb.lights_on
                seen[f.index] = tb.considered
        _strip(ax, t_all, seen, -0.16, 1.16, "#000000", alpha=0.05)
        if actor.is_ev:
            _strip(ax, t_all, lit, -0.14, -0.05, "#f2b600")
        # the smoothed state (T = DISPLAY_T) as a strip at the top
        for st, col in state_colour.items():
            mask = np.zeros(scene.num_frames + 1, dtype=bool)
            for r in rs:
                if r.states[DISPLAY_T] is st:
                    mask[r.frame] = True
            _strip(ax, t_all, mask, 1.05, 1.14, col)
        for k, tid in enumerate(sorted({r.track_id for r in rs})):
            tr = [r for r in rs if r.track_id == tid]
            tt = np.array([r.frame / fps for r in tr])
            p = np.array([np.nan if r.probability is None else r.probability for r in tr])
            colour = _TRACK_COLOURS[k % len(_TRACK_COLOURS)]
            ax.plot(tt, p, ".", ms=3.5, color=colour, alpha=0.75)
            ax.plot(tt, [r.positive_fraction for r in tr], "-", lw=1.8, color=colour)
            ax.annotate(
                f"#{tid}", (tt[0], 0.9), fontsize=7, color=colour, xytext=(1, 0), textcoords="offset points"
            )
            tn = np.array([r.frame / fps for r in tr if r.probability is None])
            if len(tn):
                ax.plot(tn, np.full(len(tn), 0.02), "|", color="grey", ms=5)
        info = ev_info.get(a)
        if info is not None:
            for key, text, dx in (("first_seen_s", "in view", -9), ("first_active_s", "active", 2)):
                if info[key] is not None:
                    ax.axvline(info[key], color="black", lw=0.8, ls=":")
                    ax.annotate(
                        text,
                        (info[key], 0.6),
                        rotation=90,
                        fontsize=7,
                        xytext=(dx, 0),
                        textcoords="offset points",
                    )
        ax.axhline(DISPLAY_T, color="black", lw=0.8, ls="--")
        ax.set_ylim(-0.16, 1.16)
        ax.set_xlim(0, t_all[-1])
        ax.set_yticks([0, 0.25, 0.5, 0.75, 1.0])
        ax.set_ylabel("probability / fraction")
        what = f"EV {a}: {actor.kind.name}" if actor.is_ev else f"vehicle {a}: ordinary {actor.kind.name}"
        where = "approaching" if actor.approaching else "receding"
        if actor.is_ev:
            extra = f", lights {actor.flash_hz:g} Hz"
        elif actor.distractor:
            extra = ", brake/tail-light glints (the most EV-like ordinary vehicle)"
        else:
            extra = " (the most EV-like ordinary vehicle)"
        n_trk = len({r.track_id for r in rs})
        ax.set_title(f"{what}, {where}{extra}; {n_trk} track(s)", loc="left", fontsize=10)
    axes[-1].set_xlabel("time (s)")
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Line2D([], [], marker=".", ls="", color="#1f77b4", label="per-frame P (one colour per track)"),
        Line2D([], [], ls="-", lw=1.8, color="#1f77b4", label="positive fraction of the 25-frame buffer"),
        Line2D([], [], marker="|", ls="", color="grey", label="crop < 18 px: no judgement"),
        Line2D([], [], ls="--", lw=0.8, color="black", label=f"T = {DISPLAY_T}"),
        Patch(color="#f2b600", label="truth: lights on"),
        Patch(color=state_colour[EVState.ACTIVE], label="state: active"),
        Patch(color=state_colour[EVState.INACTIVE], label="state: inactive"),
        Patch(color=state_colour[EVState.WARMING_UP], label="state: warming up"),
        Patch(color="#000000", alpha=0.08, label="vehicle in view"),
    ]
    fig.legend(handles=handles, loc="outside upper center", ncol=5, fontsize=8, frameon=False)
    fig.savefig(path)


def plot_sweep(path: Path, metrics: dict[str, Any]) -> None:
    """Precision / recall vs smoother threshold T: per actor, per frame, and the raw classifier."""
    sm = metrics["smoother"]
    cls = metrics["classifier"]
    ts = np.array(THRESHOLDS)
    fig = _figure(7.5, 4.6)
    ax = fig.subplots()
    for key, colour in (("precision", "#1f77b4"), ("recall", "#d62728")):
        pa = [sm["per_actor"][str(t)][key] for t in THRESHOLDS]
        pf = [sm["per_frame"][str(t)][key] for t in THRESHOLDS]
        ax.plot(ts, pa, "o-", color=colour, lw=2, label=f"per actor {key} (ever active)")
        ax.plot(ts, pf, "s--", color=colour, lw=1.3, label=f"per frame smoothed {key}")
        ax.axhline(cls[key], color=colour, lw=1, ls=":", label=f"raw per-frame classifier {key}")
    ax.axvline(DISPLAY_T, color="grey", lw=0.8)
    ax.set_xticks(ts)
    ax.set_xlabel("smoother threshold T (positive fraction must exceed T)")
    ax.set_ylabel("fraction")
    ax.set_ylim(0, 1.05)
    ax.set_title("Output smoother threshold sweep (window 25, ≥ 6 valid frames)")
    ax.legend(fontsize=7.5, loc="lower right")
    ax.grid(alpha=0.3)
    fig.savefig(path)


# ------------------------------------------------------------------------------------------- report
