"""Precision–recall curve plot of a per-frame / per-crop EV classifier (SPEC §1 metrics).

:func:`plot_pr_curve` draws the curve from :func:`makeway.eval.classification.pr_curve`, marks the
classifier's operating point (its decision threshold) and the max-F1 point, draws the recall-0.8
line with the best precision there, and writes a PNG all-or-nothing (matplotlib, Agg backend; no
pyplot state is touched).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from makeway.atomic import atomic_path
from makeway.eval.classification import pr_curve, threshold_metrics

__all__ = ["plot_pr_curve"]


def plot_pr_curve(
    scores: np.ndarray,
    labels: np.ndarray,
    path: str | Path,
    *,
    threshold: float = 0.5,
    title: str = "EV classifier: precision–recall",
    dpi: int = 120,
) -> Path:
    """Write the PR curve of ``scores`` against 0/1 ``labels`` to ``path`` (PNG); returns the path.

    Raises:
        ValueError: no positive label (the curve is undefined).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    y = np.asarray(labels).astype(bool).ravel()
    s = np.asarray(scores, dtype=np.float64).ravel()
    curve = pr_curve(s, y)
    if curve["recall"].size == 0:
        raise ValueError("a precision-recall curve needs at least one positive label and one score")
    thr = threshold_metrics(s, y, recall_at=0.8)
    pred = s >= threshold
    tp = int(np.sum(pred & y))
    op_p = tp / max(int(pred.sum()), 1)
    op_r = tp / int(y.sum())
    best = int(np.argmax(curve["threshold"] == thr["max_f1_threshold"]))
    base = float(y.mean())

    fig = Figure(figsize=(5.2, 4.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    rec = np.r_[0.0, curve["recall"]]
    prec = np.r_[curve["precision"][0], curve["precision"]]
    ax.step(rec, prec, where="post", color="tab:blue", lw=1.8, label="PR curve")
    ax.axhline(base, color="grey", ls=":", lw=1, label=f"chance (positive rate {base:.2f})")
    ax.axvline(
        0.8,
        color="tab:green",
        ls="--",
        lw=1,
        label=f"recall 0.8: best precision {thr['precision_at_recall_0.8']:.3f}",
    )
    ax.plot(
        curve["recall"][best],
        curve["precision"][best],
        "o",
        ms=9,
        mfc="none",
        mec="tab:orange",
        mew=2,
        label=f"max-F1 {thr['max_f1']:.3f} (t = {thr['max_f1_threshold']:.2f})",
    )
    ax.plot(
        op_r,
        op_p,
        "s",
        ms=7,
        color="tab:red",
        label=f"operating point t = {threshold:g}: P {op_p:.3f} R {op_r:.3f}",
    )
    ax.set_xlim(0.0, 1.02)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_title(f"{title}\n{len(y)} samples, {int(y.sum())} positive", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=7.5)
    fig.tight_layout()
    target = Path(path)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return target
