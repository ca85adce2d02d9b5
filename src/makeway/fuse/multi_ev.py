"""Several emergency vehicles at once, each one track fed by every sense (SPEC §7; issue 26 item 2).

:class:`MultiEVFusion` keeps one track per EV and turns what the senses report in one control step
into one :class:`~makeway.messages.EVBelief` per confirmed track.

**Observations** (each with its covariance):

* siren — a :class:`~makeway.messages.SirenObservation`; every source heard is one observation:
  the bearing (vehicle frame) with ``siren_bearing_sigma_deg``, and the distance, when the listener
  gives one below ``siren_far_m`` (the networks' distance saturates beyond: a bearing only there),
  with ``max(s·d, siren_distance_sigma_min_m)``, where ``s`` is the source's ``distance_sigma`` (σ
  of ln distance) when the listener states one. Otherwise ``s`` is ``siren_distance_sigma_frac``
  up to ``siren_compressed_from_m`` and grows linearly to ``siren_distance_sigma_far`` at
  ``siren_far_m``: the siren networks read a siren 100–300 m away as 30–50 m, so a distance read
  there says little of where the siren is. A fixed 25 % there would let a run of such readings
  pin an approaching EV's track at 40 m with a confident, near-zero closing speed, so that the
  cameras' fixes of the real EV fall outside its gate as it arrives (and a new track is born
  behind the car as it passes), and pull a receding EV's track back to 40 m, approaching;
* light — a :class:`~makeway.messages.LightObservation`: azimuth (vehicle frame) and optional
  range, each with its own standard deviation;
* V2X — a :class:`~makeway.messages.V2XObservation` (world frame): position, heading and speed,
  dead-reckoned from the alert's time to the step's time (the position covariance grows with the
  velocity's by ``dt²``); only ``verified`` alerts are used.

**Track.** A constant-velocity extended Kalman filter in the world frame, state ``(x, y, v_x, v_y)``
(m, m/s), white acceleration noise ``accel_noise_mps2`` on each axis. Measurement models, with ego
position ``(x_e, y_e)`` and yaw ``ψ`` and ``Δ = (x − x_e, y − y_e)``, ``r = |Δ|``:

* polar: bearing ``atan2(Δy, Δx) − ψ`` (Jacobian ``(−Δy/r², Δx/r², 0, 0)``) and optionally range
  ``r`` (Jacobian ``(Δx/r, Δy/r, 0, 0)``); the bearing innovation is wrapped to ``(−π, π]``;
* Cartesian (V2X): the whole state, ``H = I₄``, velocity covariance from speed and heading
  (``σ_v`` along the heading, ``v·σ_heading`` across it).

**Association.** Per step, senses in the order V2X, light, siren (the most precise first, so the
later ones meet tracks already corrected). For each sense, the squared Mahalanobis distance
``d² = νᵀS⁻¹ν`` of every track × observation pair; pairs beyond the chi-square gate (``gate_prob``
quantile for the measurement's dimension) are barred; global nearest neighbour
(:func:`scipy.optimize.linear_sum_assignment`) picks at most one observation per track and one track
per observation, minimising the total negative log-likelihood ``d² + ln det(2πS)`` (``d²`` alone
would hand a new, broad track the observations of an established, sharp one on the same EV).

**Birth and death.** An observation outside every track's birth gate (the ``birth_gate_prob``
quantile, wider than the association gate, so that a rare outlier of a tracked EV does not start a
second track) starts a *tentative* track: from V2X the
observed state; from bearing and range the polar fix with zero velocity (``initial_speed_sigma_mps``);
from a bearing only, a point at ``prior_range_m`` along the bearing with the wide range prior
``prior_range_sigma_m``. A *scan* is a step with at least one observation; a tentative track is
confirmed once ``confirm_m`` of its last ``confirm_n`` scans supported it, or at once by a verified
V2X alert (signed by a trusted EV: not clutter), or once ``confirm_senses_m`` (4) scans in a
row supported it with two senses among them (a siren and a light on one bearing: clutter in each
sense is independent of the other's, so their agreement is evidence that one sense needs 7 windows
to give; an EV 50 m behind whose light bar the rear camera catches as its siren is first heard is
confirmed 0.5 s sooner), and dropped when its first ``confirm_n`` scans did
not confirm it. The default 7 of 9 keeps a listener that reports a siren at a random bearing in every
window from confirming any track (none in 10 runs of 30 s at 6 Hz; 4 of 6 confirmed 1.7 per run);
a real siren alone is confirmed after 7 windows (1.2 s), with lights at 10 Hz in 0.7 s. Any track
without support for ``lost_after_s`` is dropped. Two tracks whose states are within ``merge_chi2``
(Mahalanobis², 4 d.o.f.) and whose bearings from the ego agree within ``merge_bearing_sigmas``
standard deviations (each track's bearing σ from its position covariance across the line of sight)
become the older one. The bearing test keeps a stale track from swallowing a new EV: a false light
ahead, unsupported for a second and a half, has a position σ of 50 m or more, and a 4-d.o.f.
Mahalanobis test alone would merge into it the track of an EV whose lights were just seen 50 m
behind (seed003, seed 7: the EV's track was lost that way and confirmed 0.8 s late). **A bearing
alone** (a light with no range, a siren with no distance) is neither gated against a track whose own
bearing from the car is unknown, nor is such a track merged with another: unknown means a bearing σ
(the position's spread across the line of sight over its distance) above
``bearing_only_max_sigma_deg``, 60° by default, as for a track a few metres from the car with a
spread of several metres. The linearised gate of such a track takes a light from any direction, and
the update drags the track to it: a false light ahead would turn a stray siren track just behind the
car into "EV ahead, 1 m away, approaching".

**Belief** per confirmed track, in the ego's vehicle frame: position, distance and bearing (position
and distance NaN while the range is unknown: radial standard deviation above ``placed_sigma_frac``
of the distance); relation (:func:`~makeway.fuse.relation.classify_relation`) once the speed is
known to ``max_speed_sigma_mps`` and above ``min_speed_mps``, else ``UNKNOWN``; approaching from the
range rate when that relation is a road's (behind, ahead, oncoming, crossing), else the listener's
last call (a track placed where no road relation fits moves as no vehicle on a road does — typically
a siren whose distances beyond the rangers' reach were compressed, which makes a crossing EV on a
collision course look like one pacing the ego — so its range rate is not trusted either). **Beyond
the rangers' reach** (``keep_call_beyond_ranging``, on by default): while the siren alone supports a
track placed ``siren_compressed_from_m`` or more away, it is receding if its range rate called it
receding when it was last placed well (a light, V2X, or a siren nearer than that), or if the
listener calls it receding, whatever its range rate says now. Placed by compressed distances, an EV
driving away sits too near with too low a speed, so the ego's own speed reads as closing, and the
listener's distance trend, fed the same readings, may call it approaching too (a car starting again
after an EV overtook it would yield to it a second time).
An approaching call is not kept: an EV seen approaching may pass the car and drive off. ``sources``
— the senses that supported the track within ``sense_hold_s``; ``confidence`` the noisy-OR
``1 − Π(1 − p_s)`` over those senses, ``p_s`` the last detector probability of sense ``s`` (the
listener's smoothed probability, the light detector's, ``v2x_confidence`` for a verified alert),
each scaled by the share of its sensor's channels the perception stage trusted. **Sensor health**:
the latest :class:`~makeway.messages.SensorHealth` of each sensor — a siren observation's ``health``
(the microphone array), or one handed in on its own, such as a vision frame's
``PerceptionFrame.health`` (a frozen or blacked-out camera) — scales its sense
(:data:`SENSE_OF_SENSOR`) and is named in every belief's ``sensor_faults``
(:meth:`~makeway.messages.SensorHealth.faults`) until the sensor reports itself healthy again.
:meth:`MultiEVFusion.most_urgent` picks the most urgent belief (what
:meth:`~makeway.fuse.source.BeliefSource.update` publishes); the yield decision reads every track's
(:meth:`FusedBeliefSource.beliefs`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from makeway.frames import to_vehicle_frame
from makeway.fuse.kalman import cv_predict, range_sigma_m
from makeway.fuse.relation import classify_relation
from makeway.messages import (
    EVBelief,
    EVRelation,
    LightObservation,
    SensorHealth,
    SirenObservation,
    V2XObservation,
    VehicleState,
)

__all__ = [
    "SENSES",
    "SENSE_HOLD_S",
    "SENSE_OF_SENSOR",
    "EVTrack",
    "FusedBeliefSource",
    "MultiEVFusion",
    "Observation",
    "cv_predict",
    "polar_model",
]

SIREN, LIGHT, V2X = "siren", "light", "v2x"
SENSES = (V2X, LIGHT, SIREN)  # association order: most precise first
SOURCE = "fused"
SENSE_HOLD_S = 1.0
"""How long (s) a sense supports a track after its last observation (``sense_hold_s``'s default)."""

Observation = SirenObservation | LightObservation | V2XObservation | SensorHealth
SENSE_OF_SENSOR = {"audio": SIREN, "camera": LIGHT}
"""The fusion sense each sensor of a :class:`~makeway.messages.SensorHealth` feeds."""

_BARRED = 1e12


def polar_model(
    state: np.ndarray, ego_x: float, ego_y: float, ego_yaw: float, with_range: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted polar measurement of states ``(T, 4)`` seen from the ego: ``(T, m)`` (bearing in
    the vehicle frame, rad; range, m) and its Jacobian ``(T, m, 4)``; ``m`` is 2 with range, else 1."""
    dx = state[:, 0] - ego_x
    dy = state[:, 1] - ego_y
    r2 = np.maximum(dx * dx + dy * dy, 1.0)
    r = np.sqrt(r2)
    m = 2 if with_range else 1
    z = np.empty((len(state), m))
    z[:, 0] = np.arctan2(dy, dx) - ego_yaw
    h = np.zeros((len(state), m, 4))
    h[:, 0, 0] = -dy / r2
    h[:, 0, 1] = dx / r2
    if with_range:
        z[:, 1] = r
        h[:, 1, 0] = dx / r
        h[:, 1, 1] = dy / r
    return z, h


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.arctan2(np.sin(a), np.cos(a))


@dataclass
class _Meas:
    """One observation ready for the filter: ``kind`` 1 (bearing), 2 (bearing, range) or 4 (state)."""

    sense: str
    kind: int
    z: np.ndarray
    r: np.ndarray
    probability: float
    approaching: bool | None = None
    siren: bool = False
    lights: bool = False


@dataclass
class EVTrack:
    """One EV track's bookkeeping (its state and covariance live in :class:`MultiEVFusion`)."""

    track_id: int
    born_s: float
    confirmed: bool = False
    scans: deque[bool] = field(default_factory=deque)
    last_support_s: float = -math.inf
    sense_time_s: dict[str, float] = field(default_factory=dict)  # last support per sense
    sense_probability: dict[str, float] = field(default_factory=dict)
    siren_approaching: bool | None = None
    placed_receding: bool = False  # the range rate called it receding while last placed well
    v2x_siren: bool = False
    v2x_lights: bool = False
    streak: int = 0  # scans in a row that supported the track
    streak_senses: set[str] = field(default_factory=set)  # the senses that gave them

    def senses(self, time_s: float, hold_s: float) -> tuple[str, ...]:
        """The senses that supported the track within ``hold_s`` of ``time_s``, in :data:`SENSES` order."""
        return tuple(s for s in SENSES if time_s - self.sense_time_s.get(s, -math.inf) <= hold_s)


class MultiEVFusion:
    """EV tracks from siren, light and V2X observations (module docstring); config in ``__init__``."""

    def __init__(
        self,
        *,
        accel_noise_mps2: float = 3.0,
        siren_bearing_sigma_deg: float = 6.0,
        siren_distance_sigma_frac: float = 0.25,
        siren_distance_sigma_min_m: float = 2.0,
        siren_far_m: float = 50.0,
        siren_compressed_from_m: float = 30.0,
        siren_distance_sigma_far: float = 0.8,
        initial_speed_sigma_mps: float = 15.0,
        prior_range_m: float = 50.0,
        prior_range_sigma_m: float = 40.0,
        gate_prob: float = 0.99,
        birth_gate_prob: float = 0.9999,
        confirm_m: int = 7,
        confirm_n: int = 9,
        confirm_senses_m: int = 4,
        lost_after_s: float = 2.0,
        merge_chi2: float = 3.0,
        merge_bearing_sigmas: float = 3.0,
        sense_hold_s: float = SENSE_HOLD_S,
        placed_sigma_frac: float = 0.5,
        min_speed_mps: float = 3.0,
        max_speed_sigma_mps: float = 4.0,
        v2x_confidence: float = 0.99,
        keep_call_beyond_ranging: bool = True,
        bearing_only_max_sigma_deg: float = 60.0,
    ) -> None:
        noises = (
            accel_noise_mps2,
            siren_bearing_sigma_deg,
            siren_distance_sigma_frac,
            siren_distance_sigma_far,
            prior_range_sigma_m,
        )
        if min(noises) <= 0:
            raise ValueError("noise levels must be > 0")
        if (
            not 0.0 < gate_prob <= birth_gate_prob < 1.0
            or not 1 <= confirm_m <= confirm_n
            or not 1 <= confirm_senses_m <= confirm_m
            or lost_after_s <= 0
        ):
            raise ValueError(
                "0 < gate_prob <= birth_gate_prob < 1, 1 <= confirm_senses_m <= confirm_m <= confirm_n, "
                "lost_after_s > 0"
            )
        if not 0.0 < bearing_only_max_sigma_deg <= 180.0:
            raise ValueError(
                f"bearing_only_max_sigma_deg must be in (0, 180], not {bearing_only_max_sigma_deg}"
            )
        self.accel_noise_mps2 = accel_noise_mps2
        self.siren_bearing_sigma_rad = math.radians(siren_bearing_sigma_deg)
        self.siren_distance_sigma_frac = siren_distance_sigma_frac
        self.siren_distance_sigma_min_m = siren_distance_sigma_min_m
        self.siren_far_m = siren_far_m
        self.siren_compressed_from_m = siren_compressed_from_m
        self.siren_distance_sigma_far = siren_distance_sigma_far
        self.initial_speed_sigma_mps = initial_speed_sigma_mps
        self.prior_range_m = prior_range_m
        self.prior_range_sigma_m = prior_range_sigma_m
        self.gate_chi2 = {m: float(chi2.ppf(gate_prob, m)) for m in (1, 2, 4)}
        self.birth_chi2 = {m: float(chi2.ppf(birth_gate_prob, m)) for m in (1, 2, 4)}
        self.confirm_m = confirm_m
        self.confirm_n = confirm_n
        self.confirm_senses_m = confirm_senses_m
        self.lost_after_s = lost_after_s
        self.merge_chi2 = merge_chi2
        self.merge_bearing_sigmas = merge_bearing_sigmas
        self.sense_hold_s = sense_hold_s
        self.placed_sigma_frac = placed_sigma_frac
        self.min_speed_mps = min_speed_mps
        self.max_speed_sigma_mps = max_speed_sigma_mps
        self.v2x_confidence = v2x_confidence
        self.keep_call_beyond_ranging = keep_call_beyond_ranging
        self.bearing_only_max_sigma_rad = math.radians(bearing_only_max_sigma_deg)
        self.reset()

    def reset(self) -> MultiEVFusion:
        """Forget every track."""
        self.tracks: list[EVTrack] = []
        self.state_ = np.zeros((0, 4))  # row i: tracks[i]'s x, y, vx, vy (world, m and m/s)
        self.cov_ = np.zeros((0, 4, 4))
        self.time_s_ = -math.inf
        self.next_id_ = 1
        self.unverified_ = 0  # V2X observations set aside because not verified
        self.health_: dict[str, SensorHealth] = {}  # the latest health per sensor
        return self

    def _note_health(self, health: SensorHealth) -> None:
        last = self.health_.get(health.sensor)
        if last is None or health.time_s >= last.time_s:
            self.health_[health.sensor] = health

    def sensor_faults(self) -> tuple[str, ...]:
        """Every channel a perception stage distrusts in its latest health (``"camera:0 frozen"``)."""
        return tuple(f for h in self.health_.values() for f in h.faults())

    def _trust(self, sense: str) -> float:
        """The share of trusted channels of the sensor feeding ``sense`` (1 without a report)."""
        return min(
            (h.trust for name, h in self.health_.items() if SENSE_OF_SENSOR.get(name) == sense),
            default=1.0,
        )

    # ------------------------------------------------------------------------------ observations

    def _measurements(self, time_s: float, observations: Iterable[Observation]) -> dict[str, list[_Meas]]:
        out: dict[str, list[_Meas]] = {s: [] for s in SENSES}
        sb2 = self.siren_bearing_sigma_rad**2
        for o in observations:
            if isinstance(o, SensorHealth):
                self._note_health(o)
                continue
            if isinstance(o, SirenObservation):
                if o.health is not None:
                    self._note_health(o.health)
                if not o.is_siren:
                    continue
                for src in o.sources:
                    d = src.distance_m
                    if d is not None and d < self.siren_far_m:
                        frac, floor = self._siren_sigma_frac(d), self.siren_distance_sigma_min_m
                        s_r = range_sigma_m(d, src.distance_sigma, frac, floor)
                        z, r = np.array([src.bearing_rad, max(d, 1.0)]), np.diag([sb2, s_r**2])
                    else:
                        z, r = np.array([src.bearing_rad]), np.array([[sb2]])
                    out[SIREN].append(
                        _Meas(SIREN, len(z), z, r, float(o.smoothed_probability), src.approaching, siren=True)
                    )
            elif isinstance(o, LightObservation):
                sa2 = o.azimuth_sigma_rad**2
                if o.range_m is not None and o.range_sigma_m is not None:
                    z, r = np.array([o.azimuth_rad, o.range_m]), np.diag([sa2, o.range_sigma_m**2])
                else:
                    z, r = np.array([o.azimuth_rad]), np.array([[sa2]])
                out[LIGHT].append(_Meas(LIGHT, len(z), z, r, float(o.probability), lights=True))
            elif isinstance(o, V2XObservation):
                if not o.verified:
                    self.unverified_ += 1
                    continue
                out[V2X].append(self._v2x_meas(time_s, o))
            else:
                raise TypeError(f"not an observation: {type(o).__name__}")
        return out

    def _siren_sigma_frac(self, d: float) -> float:
        """σ of ln distance for a siren distance ``d`` (m) read without one: ``siren_distance_sigma_frac``
        up to ``siren_compressed_from_m``, rising linearly to ``siren_distance_sigma_far`` at
        ``siren_far_m`` (module docstring)."""
        lo, hi = self.siren_compressed_from_m, self.siren_far_m
        if hi <= lo:
            return self.siren_distance_sigma_frac
        return float(np.interp(d, (lo, hi), (self.siren_distance_sigma_frac, self.siren_distance_sigma_far)))

    def _v2x_meas(self, time_s: float, o: V2XObservation) -> _Meas:
        c, s = math.cos(o.heading_rad), math.sin(o.heading_rad)
        dt = max(0.0, time_s - o.time_s)
        vx, vy = o.speed_mps * c, o.speed_mps * s
        rot = np.array([[c, -s], [s, c]])
        rv = rot @ np.diag([o.speed_sigma_mps**2, (o.speed_mps * o.heading_sigma_rad) ** 2]) @ rot.T
        r = np.zeros((4, 4))
        r[:2, :2] = o.position_sigma_m**2 * np.eye(2) + dt * dt * rv
        r[:2, 2:] = r[2:, :2] = dt * rv
        r[2:, 2:] = rv
        z = np.array([o.x_m + vx * dt, o.y_m + vy * dt, vx, vy])
        return _Meas(V2X, 4, z, r, self.v2x_confidence, siren=o.siren, lights=o.lights)

    # ------------------------------------------------------------------------------------ update

    def update(
        self, time_s: float, ego: VehicleState, observations: Sequence[Observation] = ()
    ) -> list[EVBelief]:
        """Advance every track to ``time_s`` (s), fold in the observations taken in this control step
        (siren and light in the ego's vehicle frame at ``ego``, V2X in the world frame) and return one
        belief per confirmed track, by track id."""
        if self.tracks and time_s > self.time_s_:
            self.state_, self.cov_ = cv_predict(
                self.state_, self.cov_, time_s - self.time_s_, self.accel_noise_mps2
            )
        self.time_s_ = max(self.time_s_, time_s)
        meas = self._measurements(time_s, observations)
        scan = any(meas.values())
        supported: set[int] = set()
        for sense in SENSES:
            if meas[sense]:
                supported |= self._associate(time_s, ego, meas[sense])
        if scan:
            for i, t in enumerate(self.tracks):
                t.scans.append(i in supported)
                if i not in supported:
                    t.streak, t.streak_senses = 0, set()
                if len(t.scans) > self.confirm_n:
                    t.scans.popleft()
                if not t.confirmed and (
                    sum(t.scans) >= self.confirm_m
                    or t.sense_time_s.get(V2X) == time_s
                    or (t.streak >= self.confirm_senses_m and len(t.streak_senses) >= 2)
                ):
                    t.confirmed = True
        self._prune(time_s, ego)
        return [self._belief(i, time_s, ego) for i, t in enumerate(self.tracks) if t.confirmed]

    def _associate(self, time_s: float, ego: VehicleState, meas: list[_Meas]) -> set[int]:
        """Gate, assign and correct one sense's observations; birth from the ungated ones. Returns
        the indices of the tracks it supported."""
        n_t, n_o = len(self.tracks), len(meas)
        cost = np.full((n_t, n_o), _BARRED)
        gated = np.zeros(n_o, dtype=bool)
        cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]] = {}
        if n_t:
            for kind in (1, 2, 4):
                cols = [j for j, m in enumerate(meas) if m.kind == kind]
                if not cols:
                    continue
                if kind == 4:
                    zhat, h = self.state_, np.broadcast_to(np.eye(4), (n_t, 4, 4))
                else:
                    zhat, h = polar_model(self.state_, ego.x_m, ego.y_m, ego.yaw_rad, kind == 2)
                z = np.stack([meas[j].z for j in cols])  # (O, m)
                r = np.stack([meas[j].r for j in cols])  # (O, m, m)
                s = (h @ self.cov_ @ h.transpose(0, 2, 1))[:, None] + r[None]  # (T, O, m, m)
                nu = z[None] - zhat[:, None]  # (T, O, m)
                if kind != 4:
                    nu[..., 0] = _wrap(nu[..., 0])
                d2 = np.einsum("toi,toi->to", nu, np.linalg.solve(s, nu[..., None])[..., 0])
                if kind == 1:
                    # a bearing alone cannot test (nor correct) a track whose own bearing is unknown
                    # (one placed a few metres from the car with a spread of several metres): the
                    # linearised gate would take a light from any direction
                    d2[self._bearing_sigma(ego) > self.bearing_only_max_sigma_rad] = np.inf
                inside = d2 <= self.gate_chi2[kind]
                nll2 = d2 + np.linalg.slogdet(s)[1] + kind * math.log(2.0 * math.pi)
                cost[:, cols] = np.where(inside, nll2, _BARRED)
                gated[cols] = (d2 <= self.birth_chi2[kind]).any(axis=0)
                cache[kind] = (h, s, nu, cols)
        rows, cols_a = linear_sum_assignment(cost) if n_t else (np.zeros(0, int), np.zeros(0, int))
        pairs = [(int(i), int(j)) for i, j in zip(rows, cols_a, strict=True) if cost[i, j] < _BARRED]
        for h, s, nu, cols in cache.values():
            where = {j: k for k, j in enumerate(cols)}
            sel = [(i, where[j]) for i, j in pairs if j in where]
            if not sel:
                continue
            ti = np.array([i for i, _ in sel])
            ok = np.array([k for _, k in sel])
            p = self.cov_[ti]
            hh = h[ti]
            ss = s[ti, ok]
            rr = ss - hh @ p @ hh.transpose(0, 2, 1)
            gain = np.linalg.solve(ss, hh @ p).transpose(0, 2, 1)  # P Hᵀ S⁻¹ (S symmetric)
            self.state_[ti] += (gain @ nu[ti, ok][..., None])[..., 0]
            joseph = np.eye(4) - gain @ hh
            self.cov_[ti] = joseph @ p @ joseph.transpose(0, 2, 1) + gain @ rr @ gain.transpose(0, 2, 1)
        for i, j in pairs:
            self._support(self.tracks[i], time_s, meas[j])
        for j, m in enumerate(meas):
            if not gated[j]:
                self._birth(time_s, ego, m)
        return {i for i, _ in pairs} | set(range(n_t, len(self.tracks)))

    def _support(self, t: EVTrack, time_s: float, m: _Meas) -> None:
        if t.last_support_s < time_s:
            t.streak += 1
        t.streak_senses.add(m.sense)
        t.last_support_s = time_s
        t.sense_time_s[m.sense] = time_s
        t.sense_probability[m.sense] = m.probability
        if m.sense == SIREN and m.approaching is not None:
            t.siren_approaching = m.approaching
        if m.sense == V2X:
            t.v2x_siren, t.v2x_lights = m.siren, m.lights

    def _birth(self, time_s: float, ego: VehicleState, m: _Meas) -> None:
        cov = np.zeros((4, 4))
        if m.kind == 4:
            state, cov = m.z.copy(), m.r.copy()
        else:
            phi = ego.yaw_rad + float(m.z[0])
            d = float(m.z[1]) if m.kind == 2 else self.prior_range_m
            s_r = math.sqrt(float(m.r[1, 1])) if m.kind == 2 else self.prior_range_sigma_m
            s_t = d * math.sqrt(float(m.r[0, 0]))
            c, s = math.cos(phi), math.sin(phi)
            rot = np.array([[c, -s], [s, c]])
            state = np.array([ego.x_m + d * c, ego.y_m + d * s, 0.0, 0.0])
            cov[:2, :2] = rot @ np.diag([s_r**2, s_t**2]) @ rot.T
            cov[2, 2] = cov[3, 3] = self.initial_speed_sigma_mps**2
        t = EVTrack(self.next_id_, born_s=time_s)
        self.next_id_ += 1
        self._support(t, time_s, m)
        self.tracks.append(t)
        self.state_ = np.vstack([self.state_, state[None]])
        self.cov_ = np.concatenate([self.cov_, cov[None]])

    def _bearing_sigma(self, ego: VehicleState, rows: slice | list[int] = slice(None)) -> np.ndarray:
        """The bearing standard deviation (rad) seen from the ego of the tracks ``rows`` (default
        all): the position's spread across the line of sight over the distance."""
        dx, dy = self.state_[rows, 0] - ego.x_m, self.state_[rows, 1] - ego.y_m
        r = np.maximum(np.hypot(dx, dy), 1.0)
        across = np.stack([-dy, dx], axis=1) / r[:, None]
        var = np.einsum("ti,tij,tj->t", across, self.cov_[rows, :2, :2], across)
        return np.sqrt(np.maximum(var, 0.0)) / r

    def _bearing(self, i: int, ego: VehicleState) -> tuple[float, float]:
        """Track ``i``'s bearing from the ego (world frame, rad) and its standard deviation (rad)."""
        dx, dy = float(self.state_[i, 0]) - ego.x_m, float(self.state_[i, 1]) - ego.y_m
        return math.atan2(dy, dx), float(self._bearing_sigma(ego, [i])[0])

    def _same_bearing(self, a: int, b: int, ego: VehicleState) -> bool:
        """Whether tracks ``a`` and ``b`` are seen on one bearing (within ``merge_bearing_sigmas``);
        never when either's bearing is unknown (σ above ``bearing_only_max_sigma_deg``)."""
        ta, sa = self._bearing(a, ego)
        tb, sb = self._bearing(b, ego)
        if max(sa, sb) > self.bearing_only_max_sigma_rad:
            return False
        gap = abs(math.atan2(math.sin(ta - tb), math.cos(ta - tb)))
        return gap <= self.merge_bearing_sigmas * math.hypot(sa, sb)

    def _prune(self, time_s: float, ego: VehicleState) -> None:
        keep = [
            time_s - t.last_support_s <= self.lost_after_s and (t.confirmed or len(t.scans) < self.confirm_n)
            for t in self.tracks
        ]
        n = len(self.tracks)
        for a in range(n):  # merge: the older of two tracks on one EV keeps it
            for b in range(a + 1, n):
                if not (keep[a] and keep[b]):
                    continue
                diff = self.state_[a] - self.state_[b]
                d2 = float(diff @ np.linalg.solve(self.cov_[a] + self.cov_[b], diff))
                if d2 < self.merge_chi2 and self._same_bearing(a, b, ego):
                    old, new = self.tracks[a], self.tracks[b]
                    for s, ts in new.sense_time_s.items():
                        if ts > old.sense_time_s.get(s, -math.inf):
                            old.sense_time_s[s] = ts
                            old.sense_probability[s] = new.sense_probability[s]
                    old.last_support_s = max(old.last_support_s, new.last_support_s)
                    old.confirmed = old.confirmed or new.confirmed
                    keep[b] = False
        if not all(keep):
            idx = [i for i, k in enumerate(keep) if k]
            self.tracks = [self.tracks[i] for i in idx]
            self.state_, self.cov_ = self.state_[idx], self.cov_[idx]

    # ------------------------------------------------------------------------------------ belief

    def _belief(self, i: int, time_s: float, ego: VehicleState) -> EVBelief:
        t = self.tracks[i]
        x, y, vx, vy = (float(v) for v in self.state_[i])
        p = self.cov_[i]
        dx, dy = x - ego.x_m, y - ego.y_m
        rel_x, rel_y = (float(v) for v in to_vehicle_frame(dx, dy, ego.yaw_rad))
        dist = math.hypot(dx, dy)
        los = np.array([dx, dy]) / max(dist, 1e-6)
        placed = math.sqrt(float(los @ p[:2, :2] @ los)) <= self.placed_sigma_frac * max(dist, 1.0)
        speed_sigma = math.sqrt(0.5 * float(p[2, 2] + p[3, 3]))
        moving = math.hypot(vx, vy) >= self.min_speed_mps and speed_sigma <= self.max_speed_sigma_mps
        relation = EVRelation.UNKNOWN
        approaching = t.siren_approaching
        by_motion = False
        if placed and moving:
            relation = classify_relation(rel_x, rel_y, math.atan2(vy, vx) - ego.yaw_rad)
            # placed where no road relation fits, the track's motion is not to be trusted (a
            # siren's distances compressed beyond the rangers' reach): the listener's call stands
            if relation is not EVRelation.UNKNOWN or approaching is None:
                c, s = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
                evx, evy = ego.vx_mps * c - ego.vy_mps * s, ego.vx_mps * s + ego.vy_mps * c
                approaching = float(los @ np.array([vx - evx, vy - evy])) < 0.0
                by_motion = True
        senses = t.senses(time_s, self.sense_hold_s)
        compressed = senses == (SIREN,) and dist >= self.siren_compressed_from_m
        if senses and not compressed:
            if by_motion:
                t.placed_receding = approaching is False
        elif (
            compressed
            and self.keep_call_beyond_ranging
            and approaching is not False
            and (t.placed_receding or (approaching is True and t.siren_approaching is False))
        ):
            # placed by compressed siren distances alone, an EV that drove off sits too near with
            # too low a speed, and the ego's own speed then reads as closing (so may the listener's
            # distance trend): a receding call made while the track was last placed well, or the
            # listener's considered receding call, outweighs the range rate
            approaching = False
        miss = 1.0
        for s_ in senses:
            miss *= 1.0 - min(max(t.sense_probability.get(s_, 0.0), 0.0), 1.0) * self._trust(s_)
        v2x_on = V2X in senses
        nan = float("nan")
        return EVBelief(
            time_s=time_s,
            detected=True,
            confidence=1.0 - miss,
            relation=relation,
            rel_x_m=rel_x if placed else nan,
            rel_y_m=rel_y if placed else nan,
            distance_m=dist if placed else nan,
            bearing_rad=math.atan2(rel_y, rel_x),
            approaching=approaching,
            lights=LIGHT in senses or (v2x_on and t.v2x_lights),
            siren=SIREN in senses or (v2x_on and t.v2x_siren),
            source=SOURCE,
            sources=senses,
            track_id=t.track_id,
            sensor_faults=self.sensor_faults(),
        )

    @staticmethod
    def most_urgent(beliefs: Sequence[EVBelief], time_s: float) -> EVBelief:
        """The most urgent belief: approaching EVs before others, then
        the nearest (an unranged one after the ranged ones), then the most confident;
        :meth:`EVBelief.nothing` at ``time_s`` without any."""
        live = [b for b in beliefs if b.detected]
        if not live:
            return EVBelief.nothing(time_s, source=SOURCE)

        def key(b: EVBelief) -> tuple[bool, float, float]:
            d = b.distance_m if math.isfinite(b.distance_m) else math.inf
            return (b.approaching is not True, d, -b.confidence)

        return min(live, key=key)


class FusedBeliefSource:
    """:class:`MultiEVFusion` behind the :class:`~makeway.fuse.source.BeliefSource` interface: the
    senses hand observations to :meth:`receive`; :meth:`update` fuses those received since the last
    call and returns the most urgent belief (the per-track ones stay in :attr:`beliefs_`)."""

    def __init__(self, fusion: MultiEVFusion | None = None) -> None:
        self.fusion = fusion if fusion is not None else MultiEVFusion()
        self._pending: list[Observation] = []
        self.beliefs_: list[EVBelief] = []

    def receive(self, observation: Observation) -> None:
        """Queue one observation for the next :meth:`update`."""
        self._pending.append(observation)

    def update(self, time_s: float, ego: VehicleState) -> EVBelief:
        """Fuse what was received and return the most urgent EV's belief at ``time_s`` (s)."""
        pending, self._pending = self._pending, []
        self.beliefs_ = self.fusion.update(time_s, ego, pending)
        return MultiEVFusion.most_urgent(self.beliefs_, time_s)

    def beliefs(self) -> list[EVBelief]:
        """One belief per confirmed EV track as of the last :meth:`update`."""
        return list(self.beliefs_)
