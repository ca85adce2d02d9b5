"""The trained siren network at run time: ONNX Runtime, no torch (issue 4, SPEC §3).

:class:`SirenModel` loads an ONNX file written by ``makeway audio train`` (see
:mod:`makeway.train.siren`), rebuilds the exact feature extractor from the file's metadata and
answers, for a batch of 0.5 s windows of the roof array:

* ``prob`` — siren probability (sigmoid of the siren logit); ``is_siren = prob ≥ threshold``;
* ``theta`` — bearing of the nearest siren (rad, vehicle frame, 0 ahead, positive left), from the
  (sin θ, cos θ) head normalised to unit length (SPEC §3);
* ``distance`` — distance of the nearest siren (m, ground plane);
* ``bearing_map`` — the per-bearing softmax of the model's bearing logits over the 360° grid (the
  direction head is its weighted mean).

:meth:`SirenModel.sources` lists the sirens of a window: the nearest from the heads, further ones
from the window's time–frequency bins (:mod:`makeway.perceive.audio.multisource`).

:data:`DEFAULT_SIREN_MODEL` is the model shipped in the package (``makeway/models/siren_net.onnx``;
model card ``docs/model_card_siren_net.md``).

**Detector and localizer.** A second network of the same kind can supply ``theta``, ``distance``
and ``bearing_map`` while the first keeps ``prob`` (``localizer=``): both read the same features,
computed once. The shipped pair is :data:`DEFAULT_SIREN_MODEL` as detector and
:data:`DEFAULT_SIREN_LOCALIZER` (trained with pitch variety, ``audio simulate --siren-pitch``) as
localizer: the variety sharpens bearing and distance but costs false alarms on real traffic, so it
does not decide whether a siren is there (model card).

**Rangers.** Further networks of the same kind can join the distance (``ranger=``): the reported
distance is then the geometric mean of the localizer's (or, without one, this network's) and the
rangers'. Networks trained on different recordings err differently, and their mean removes part of
the error. The shipped rangers are :data:`DEFAULT_SIREN_RANGERS` (three networks trained on sirens
emitted at 110–120 dB at 1 m). :data:`WIDE_SIREN_RANGERS` are two networks trained on sirens of
105–140 dB, the real range with margin (issue 25): with the localizer they were chosen on validation
recordings at 105–140 dB (the mean over the 5 dB bands of 110–135 dB of the median distance error
at 10–50 m) and place loud sirens far better, quiet ones somewhat worse (model card). Each set
has its own approaching/receding classifier, trained on its distances
(:data:`~makeway.perceive.audio.motion.APPROACH_MODELS`; the listener picks it from the rangers it
runs). The wide set is not the default: in the closed loop heard by the siren stack, even with its
own classifier, it gave twice the extra yields of the default rangers (8 against 4 in 18 runs at
110–135 dB), though more expected actions (17 against 15; model card, "In the closed loop").
``ranger=WIDE_SIREN_RANGERS`` (``--ranger`` on the command line, once per file) selects them.

**Combination.** :data:`LOCALIZER_DISTANCE` says whether the localizer's distance joins the
shipped rangers' (``localizer_distance=`` overrides it); :func:`combine_distances` is the rule.

**Uncertainty.** A network trained with ``makeway audio train --distance-sigma`` has a fifth ONNX
output, :data:`SIGMA_OUTPUT`: ln σ, σ the spread of the error of ln distance it expects for the
window. It is read when present (``SirenPrediction.distance_sigma``; ``None`` for older files);
the distance's ±1σ interval is ``distance · e^(±σ)``. For a mean of networks, σ is the root mean
square of the members' σ (their errors share the level ambiguity, so averaging does not shrink
it); when a member without σ (the localizer) joins, that RMS is multiplied by
:data:`SIGMA_SCALE_UNRATED`, fitted on validation recordings so that ±1σ holds 68 % of the errors
(:func:`combine_distances`).

**Calibration.** The networks read absolute levels at the scale they were trained at
(:attr:`SirenModel.full_scale_db_spl`, from the ONNX metadata; 135 dB SPL for every shipped one and
for files written before the key existed). :meth:`SirenModel.predict` rescales the windows of an
array with another ``full_scale_db_spl`` (:mod:`makeway.sense.recording`, **Calibration**).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.onnx_models import open_makeway_onnx
from makeway.perceive.audio.siren_features import SirenFeatureConfig, SirenFeatures
from makeway.registry import Registry
from makeway.sense.recording import REFERENCE_FULL_SCALE_DB_SPL, calibration_gain

__all__ = [
    "DEFAULT_SIREN_LOCALIZER",
    "DEFAULT_SIREN_MODEL",
    "DEFAULT_SIREN_RANGER",
    "DEFAULT_SIREN_RANGERS",
    "PRIOR_SIREN_RANGERS",
    "SIGMA_SCALE_UNRATED",
    "SIREN_RANGER_SETS",
    "WIDE_SIREN_RANGERS",
    "SirenModel",
    "SirenPrediction",
    "combine_distances",
    "ranger_set_name",
]

DEFAULT_SIREN_MODEL = Path(__file__).resolve().parents[2] / "models" / "siren_net.onnx"
DEFAULT_SIREN_LOCALIZER = Path(__file__).resolve().parents[2] / "models" / "siren_localizer.onnx"
DEFAULT_SIREN_RANGER = Path(__file__).resolve().parents[2] / "models" / "siren_ranger.onnx"
PRIOR_SIREN_RANGERS = (
    DEFAULT_SIREN_RANGER,
    Path(__file__).resolve().parents[2] / "models" / "siren_ranger2.onnx",
    Path(__file__).resolve().parents[2] / "models" / "siren_ranger3.onnx",
)
"""The rangers trained on sirens of 110–120 dB at 1 m only (``siren_ranger``, ``siren_ranger2``,
``siren_ranger3``): the default (:data:`DEFAULT_SIREN_RANGERS`)."""
WIDE_SIREN_RANGERS = (
    Path(__file__).resolve().parents[2] / "models" / "siren_ranger_wide.onnx",
    Path(__file__).resolve().parents[2] / "models" / "siren_ranger_wide2.onnx",
)
"""Two rangers trained on sirens of 105–140 dB at 1 m, each with the distance uncertainty output
(model card ``docs/model_card_siren_net.md``, "Rangers over the real siren levels"); averaged with
the localizer's distance (:data:`LOCALIZER_DISTANCE`)."""
DEFAULT_SIREN_RANGERS = PRIOR_SIREN_RANGERS
"""The rangers used unless told otherwise (module docstring, **Rangers**)."""
SIREN_RANGER_SETS: Registry[tuple[Path, ...]] = Registry(
    "ranger set", {"prior": PRIOR_SIREN_RANGERS, "wide": WIDE_SIREN_RANGERS}
)
"""The shipped ranger sets by name (``prior``, ``wide``). Each has its own approaching/receding
classifier, trained on that set's distances (:data:`~makeway.perceive.audio.motion.APPROACH_MODELS`,
same names)."""


def ranger_set_name(rangers: Sequence[str | Path]) -> str | None:
    """The name in :data:`SIREN_RANGER_SETS` of the set whose files are ``rangers`` (compared by
    file name, in any order), or ``None`` for any other combination."""
    names = sorted(Path(r).name for r in rangers)
    for name, members in SIREN_RANGER_SETS.items():
        if names == sorted(p.name for p in members):
            return name
    return None


SIGMA_OUTPUT = "distance_log_sigma"
"""Name of the optional ONNX output of networks trained with ``makeway audio train
--distance-sigma``: ln σ of the ln distance error the network expects (module docstring)."""
SIGMA_SCALE_UNRATED = 1.094
"""Factor on the σ of a combination in which members without σ (the localizer) join members with
one (:func:`combine_distances`). Their errors are not in the members' σ: with the localizer and
:data:`WIDE_SIREN_RANGERS`, ±1σ of the plain RMS held 63 % of the ln distance errors at 5–100 m on
validation recordings (seeds 77 + 78, sirens of 105–140 dB at 1 m; a calibrated Gaussian: 68 %).
The factor is the 68.3 % quantile of ``|ln d̂ − ln d| / σ`` there
(``benchmarks/bench_audio_range_levels.py``, "σ scale"; model card)."""
LOCALIZER_DISTANCE = True
"""Whether the localizer's distance (or, without a localizer, this network's) joins the shipped
rangers' in the geometric mean when the rangers are the shipped ones (``ranger=True``); named
rangers are always averaged with it unless ``localizer_distance=False``."""

MAX_SOURCES = 3
"""At most this many sirens are reported per window (the nearest plus two)."""
NEAR_ALONE_M = 10.0
"""No further siren is reported while the nearest is closer than this: a siren passing at a few
metres sweeps tens of degrees of bearing within one 0.5 s window, and its smeared bins look like
a second siren (chosen on training-split recordings; see docs/results.md, section "Two sirens at once")."""


@dataclass(frozen=True)
class SirenPrediction:
    """Outputs for ``n`` windows (see the module docstring)."""

    prob: np.ndarray
    theta: np.ndarray
    distance: np.ndarray
    bearing_map: np.ndarray | None
    distance_sigma: np.ndarray | None = None
    """σ of ln distance per window (the distance's ±1σ interval is ``distance · e^(±σ)``), from
    networks with the uncertainty output (module docstring, **Uncertainty**); ``None`` without."""

    def __len__(self) -> int:
        return len(self.prob)


def combine_distances(
    members: Sequence[SirenPrediction], unrated_scale: float = SIGMA_SCALE_UNRATED
) -> tuple[np.ndarray, np.ndarray | None]:
    """The combined distance of several networks: the geometric mean of their distances, and the
    root mean square of the σ of ln distance of those members that give one (``None`` when none
    does), times ``unrated_scale`` (:data:`SIGMA_SCALE_UNRATED`) when some members give none. The
    RMS is the spread of one member, not of the mean: the members share the level cue and its
    ambiguity, so their errors are far from independent."""
    dists = np.array([m.distance for m in members], dtype=np.float64)
    with np.errstate(divide="ignore"):
        distance = np.exp(np.mean(np.log(np.maximum(dists, 0.0)), axis=0))
    sigmas = [m.distance_sigma for m in members if m.distance_sigma is not None]
    if not sigmas:
        return distance, None
    sigma = np.sqrt(np.mean(np.square(sigmas), axis=0))
    return distance, sigma * unrated_scale if len(sigmas) < len(members) else sigma


class SirenModel:
    """ONNX siren network + its feature extractor (module docstring).

    Args:
        path: the ``.onnx`` file (default: :data:`DEFAULT_SIREN_MODEL`).
        threads: ONNX Runtime intra-op threads (``None``: all cores).
        threshold: decision threshold (``None``: the one stored in the model).
        localizer: a second siren network whose bearing and distance replace this one's (module
            docstring): a path, ``True`` (:data:`DEFAULT_SIREN_LOCALIZER` when ``path`` is the
            default model, none otherwise) or ``False`` (none).
        ranger: further siren networks whose distances are averaged in (geometric mean; module
            docstring): a path or a sequence of paths, ``True`` (:data:`DEFAULT_SIREN_RANGERS`
            when ``path`` is the default model, none otherwise) or ``False`` (none).
        localizer_distance: whether the localizer's (or this network's) distance joins the
            rangers' in the mean (``None``: :data:`LOCALIZER_DISTANCE` with the shipped rangers,
            ``True`` with named ones). Without rangers it is the distance whatever this says.
    """

    def __init__(
        self,
        path: str | Path | None = None,
        *,
        threads: int | None = None,
        threshold: float | None = None,
        localizer: str | Path | bool = True,
        ranger: str | Path | bool | Sequence[str | Path] = True,
        localizer_distance: bool | None = None,
    ) -> None:
        self.path = Path(path) if path is not None else DEFAULT_SIREN_MODEL
        self.session, meta = open_makeway_onnx(
            self.path, "siren_net", threads=threads, missing_hint="train one with `makeway audio train`"
        )
        try:
            streams, features = json.loads(meta["streams"]), json.loads(meta["features"])
            if not isinstance(streams, list) or not all(isinstance(x, str) for x in streams):
                raise ValueError("streams must be a list of names")
            if not isinstance(features, dict):
                raise ValueError("features must be a mapping")
            self.streams: tuple[str, ...] = tuple(streams)
            self.features = SirenFeatures(SirenFeatureConfig.from_dict(features))
            stored = float(meta.get("threshold", "0.5"))
            # models written before the key existed were all trained at the reference scale
            self.full_scale_db_spl = float(meta.get("full_scale_db_spl", REFERENCE_FULL_SCALE_DB_SPL))
        except (KeyError, ValueError, TypeError, ArithmeticError) as exc:
            raise InputError(
                self.path, f"malformed siren model metadata ({type(exc).__name__}: {exc})"
            ) from None
        self.threshold = float(threshold) if threshold is not None else stored
        self.metadata: dict[str, str] = dict(meta)
        names = [i.name for i in self.session.get_inputs()]
        if names != list(self.streams):
            raise InputError(self.path, f"model inputs {names} do not match its streams {list(self.streams)}")
        outputs = [o.name for o in self.session.get_outputs()]
        if len(outputs) < 4:
            raise InputError(self.path, f"a siren model has at least 4 outputs, this one {len(outputs)}")
        # optional: only networks trained with the uncertainty head have it (older files do not)
        self._sigma_output = outputs.index(SIGMA_OUTPUT) if SIGMA_OUTPUT in outputs else None
        located = self._named(localizer, (DEFAULT_SIREN_LOCALIZER,))
        self.localizer = self._companion(located[0], "localizer", threads) if located else None
        self.rangers: tuple[SirenModel, ...] = tuple(
            self._companion(p, "ranger", threads) for p in self._named(ranger, DEFAULT_SIREN_RANGERS)
        )
        self.localizer_distance = (
            bool(localizer_distance)
            if localizer_distance is not None
            else (LOCALIZER_DISTANCE if ranger is True else True)
        )
        self.near_alone_m = NEAR_ALONE_M
        self.separator: Any = None
        """The :class:`~makeway.perceive.audio.multisource.SourceSeparator` that :meth:`sources`
        uses for further sirens (created on first use with its default constants; may be replaced)."""

    def _named(self, which: str | Path | bool | Sequence[str | Path], defaults: Sequence[Path]) -> list[Path]:
        """The companion files named by ``which`` (class docstring): ``True`` gives the shipped
        ``defaults`` that exist when this is the default model (none otherwise), ``False`` none."""
        if which is True:
            is_default = self.path.resolve() == DEFAULT_SIREN_MODEL.resolve()
            return [p for p in defaults if p.is_file()] if is_default else []
        if which is False:
            return []
        return [Path(which)] if isinstance(which, str | Path) else [Path(w) for w in which]

    def _companion(self, path: Path, role: str, threads: int | None) -> SirenModel:
        """The localizer or ranger network at ``path``, checked to read the same features as this
        one."""
        other = SirenModel(path, threads=threads, localizer=False, ranger=False)
        if (
            other.features.config != self.features.config
            or not set(other.streams) <= set(self.streams)
            or other.full_scale_db_spl != self.full_scale_db_spl
        ):
            raise InputError(
                path,
                f"this {role} reads other features than the detector {self.path.name} "
                "(both must be trained with the same feature settings, streams and calibration)",
            )
        return other

    def __repr__(self) -> str:
        loc = f", localizer={self.localizer.path.name}" if self.localizer is not None else ""
        if self.rangers:
            loc += f", ranger={'+'.join(r.path.name for r in self.rangers)}"
        streams = list(self.streams)
        return f"SirenModel({self.path.name}, streams={streams}, threshold={self.threshold:g}{loc})"

    @property
    def config(self) -> SirenFeatureConfig:
        return self.features.config

    @property
    def mics(self) -> np.ndarray:
        return np.asarray(self.config.mics, dtype=np.float64)

    def check_array(self, mics: np.ndarray, sample_rate: int, source: str | Path) -> None:
        """Raise :class:`InputError` naming ``source`` unless the recording's array and sample rate
        are the ones the model was trained for."""
        m = np.asarray(mics, dtype=np.float64)
        if int(sample_rate) != self.config.sample_rate:
            raise InputError(
                source,
                f"sample rate {sample_rate} Hz, but the siren model expects {self.config.sample_rate} Hz",
            )
        if m.shape != self.mics.shape or not np.allclose(m, self.mics, atol=5e-3):
            raise InputError(
                source,
                f"microphone array ({len(m)} capsules) differs from the one the siren model was trained "
                f"for ({len(self.mics)} capsules, the reference roof array); use --baseline for other arrays",
            )

    def run_features(self, feats: dict[str, np.ndarray]) -> SirenPrediction:
        """Run the network on precomputed features (``SirenFeatures.transform`` output); with a
        localizer, its bearing, distance and bearing map replace this network's; with rangers,
        the distance is the geometric mean of the rangers' and (with :attr:`localizer_distance`)
        that one (:func:`combine_distances`)."""
        own = self._run_own(feats)
        out = own if self.localizer is None else self.localizer._run_own(feats)
        if not self.rangers:
            return SirenPrediction(own.prob, out.theta, out.distance, out.bearing_map, out.distance_sigma)
        members = [r._run_own(feats) for r in self.rangers]
        if self.localizer_distance:
            members.insert(0, out)
        distance, sigma = combine_distances(members)
        return SirenPrediction(own.prob, out.theta, distance, out.bearing_map, sigma)

    def run_alone(self, feats: dict[str, np.ndarray]) -> SirenPrediction:
        """This network's own outputs on precomputed features, without its localizer or rangers
        (e.g. to compare ways of combining several networks on the same windows)."""
        return self._run_own(feats)

    def _run_own(self, feats: dict[str, np.ndarray]) -> SirenPrediction:
        outs = self.session.run(
            None, {s: np.ascontiguousarray(feats[s], dtype=np.float32) for s in self.streams}
        )
        logit, direction, distance, bearing_logits = outs[:4]
        sigma = None
        if self._sigma_output is not None:
            sigma = np.exp(np.asarray(outs[self._sigma_output], dtype=np.float64))
        prob = 1.0 / (1.0 + np.exp(-np.asarray(logit, dtype=np.float64)))
        theta = np.arctan2(direction[:, 0], direction[:, 1]).astype(np.float64)
        bmap = None
        if bearing_logits.shape[1] == self.config.n_azimuth:
            z = bearing_logits - bearing_logits.max(axis=1, keepdims=True)
            e = np.exp(z)
            bmap = e / e.sum(axis=1, keepdims=True)
        dist = np.maximum(np.asarray(distance, dtype=np.float64), 0.0)
        return SirenPrediction(prob, theta, dist, bmap, sigma)

    def predict(self, windows: np.ndarray, full_scale_db_spl: float | None = None) -> SirenPrediction:
        """Outputs for ``windows (n, channels, samples)`` or one ``(channels, samples)`` window of
        an array whose full scale stands for ``full_scale_db_spl`` dB SPL (``Recording
        .full_scale_db_spl``; ``None``: taken to be the model's own scale,
        :attr:`full_scale_db_spl`). The windows are brought to the model's scale first
        (:func:`~makeway.sense.recording.calibration_gain`): the level stream, and with it the
        distance, reads absolute levels."""
        gain = calibration_gain(full_scale_db_spl, self.full_scale_db_spl)
        w = np.asarray(windows)
        return self.run_features(self.features.transform(w * np.float32(gain) if gain != 1.0 else w))

    def sources(
        self,
        pred: SirenPrediction,
        i: int,
        window: np.ndarray | None = None,
        *,
        is_siren: bool | None = None,
    ) -> list[dict[str, Any]]:
        """The sirens of window ``i``: first the nearest (the network's bearing and distance), then,
        when the raw ``window (channels, samples)`` is given, up to :data:`MAX_SOURCES` − 1 further
        sirens from :class:`~makeway.perceive.audio.multisource.SourceSeparator` (bearing only,
        ``distance_m`` None) — none while the nearest is closer than ``near_alone_m``
        (:data:`NEAR_ALONE_M`). Empty when window ``i`` is not a siren: its probability is below
        the threshold, or ``is_siren`` (a decision made elsewhere, e.g. smoothed over windows) is
        ``False``."""
        if not (pred.prob[i] >= self.threshold if is_siren is None else is_siren):
            return []
        nearest = float(pred.theta[i])
        out: list[dict[str, Any]] = [
            {"bearing_rad": nearest, "distance_m": float(pred.distance[i]), "rank": 0}
        ]
        if window is None or float(pred.distance[i]) < self.near_alone_m:
            return out
        if self.separator is None:
            from makeway.perceive.audio.multisource import SourceSeparator

            self.separator = SourceSeparator(self.mics, self.config.sample_rate)
        for theta in self.separator.further(window, [nearest], MAX_SOURCES):
            out.append({"bearing_rad": theta, "distance_m": None, "rank": len(out)})
        return out
