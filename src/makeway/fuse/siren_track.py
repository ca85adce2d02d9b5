"""One emergency-vehicle track from what the siren listener hears (SPEC §7: fusion into one EV
track with bearing, range, approaching/receding and confidence; SPEC §3 gives the observations).

:class:`SirenTrackFusion` turns each :class:`~makeway.messages.SirenObservation` (one per 0.5 s
window, every 0.17 s) and the ego pose into the :class:`~makeway.messages.EVBelief` the yield
decision reads:

* **Track.** The nearest siren's bearing θ and distance d are placed in the world frame
  (``ego + R(yaw)·d·(cos θ, sin θ)``) and filtered by a constant-velocity Kalman filter on
  ``(x, y, v_x, v_y)``. The measurement noise is polar — ``distance_sigma_frac·d``, or ``σ·d``
  when the listener states ``distance_sigma``, the σ of ln distance (at least
  ``distance_sigma_min_m``), along the line of sight, ``d·bearing_sigma_deg`` across it — rotated
  into the world frame, so a far siren's distance counts for little. A fix farther than
  ``gate_chi2`` (Mahalanobis², 2 d.o.f.) from the prediction is set aside; after ``max_misses`` of
  them in a row the track restarts on the new fix (another siren, or a wrong first fix).
  Without a siren for ``lost_after_s`` the track is dropped.
* **Relation** (behind, ahead, oncoming, crossing: :func:`~makeway.fuse.relation.classify_relation`)
  from the filtered position and the track's heading, once ``min_fixes`` fixes are in, its speed
  is known to ``max_speed_sigma_mps`` and it moves faster than ``min_speed_mps``; ``UNKNOWN``
  before (the yield decision treats a heard, unplaced siren conservatively). Once told, a relation
  is kept while the heading is uncertain again.
* **Far sirens.** The networks' distance is informative up to about 50 m and saturates beyond: a
  siren much farther away is put at a few tens of metres (they were trained to 100 m; see
  docs/results.md, section "Closed loop heard by the siren stack"). A fix is *far* when the
  networks put it at ``far_m`` or more, or when its level in the siren band is so low that even
  the quietest siren (``quiet_siren_db_1m``, the low end of road sirens' 110–120 dB at 1 m) would
  be ``far_m`` away, or (with the far ranger, opt-in) when the listener gives it a far
  probability of :data:`~makeway.perceive.audio.far_range.FAR_CALL_PROBABILITY` or more. A far
  fix counts as a bearing with a
  weak distance (radial sigma = the distance itself), and the belief then gives the bearing with
  distance and position unknown (NaN). Once the track has been in range, the relation and the
  approach call stay those of the last fix in range (an EV that went by stays gone by) until
  ``near_after`` fixes in a row are in range again; before it has ever been in range, the
  relation is the track's, and approaching is unknown until the track has seen an EV on a
  crossing road close in on the ego's road or leave it (below), and then that call.
* **Approaching.** Within ``far_m``, the listener's call for the nearest siren (the distance-trend
  classifier, :class:`~makeway.perceive.audio.motion.TrendApproach`) through a leaky log-odds
  filter: ``L ← approach_decay·L + logit(p)``, approaching when ``L ≥ approach_log_odds``,
  receding when ``L ≤ −approach_log_odds``, unchanged in between (one stray window does not flip
  it). For an EV on a crossing road, approaching means closing in on the ego's road (its offset
  across the road shrinking, from the track), which works far away too; once made, that call
  changes only after ``crossing_flip_fixes`` fixes in a row disagree (1 s: a far track's heading
  wobbles as the ego drives past the crossing road).
* **Confidence** is the listener's smoothed probability, **detected** its decision. When the
  listener distrusted capsules of the array (the observation's ``health``), the confidence is
  scaled by the share of capsules it trusted and the belief's ``sensor_faults`` names them.

Position, distance and bearing in the belief are the filtered ones, relative to the ego (vehicle
frame); beyond ``far_m`` only the bearing. A siren heard without a distance (the classical
fallback) gives a bearing only and relation ``UNKNOWN``.
"""

from __future__ import annotations

import math

import numpy as np

from makeway.frames import to_vehicle_frame
from makeway.fuse.kalman import cv_predict, range_sigma_m
from makeway.fuse.relation import classify_relation
from makeway.messages import EVBelief, EVRelation, SirenObservation
from makeway.perceive.audio.far_range import FAR_CALL_PROBABILITY

SOURCE = "siren"


class SirenTrackFusion:
    """The siren's EV track and the belief it gives (module docstring); config in ``__init__``."""

    def __init__(
        self,
        *,
        accel_noise_mps2: float = 3.0,
        bearing_sigma_deg: float = 6.0,
        distance_sigma_frac: float = 0.25,
        distance_sigma_min_m: float = 2.0,
        initial_speed_sigma_mps: float = 15.0,
        gate_chi2: float = 13.8,
        max_misses: int = 3,
        lost_after_s: float = 3.0,
        min_fixes: int = 6,
        min_speed_mps: float = 3.0,
        max_speed_sigma_mps: float = 4.0,
        far_m: float = 50.0,
        near_after: int = 4,
        crossing_flip_fixes: int = 6,
        quiet_siren_db_1m: float = 110.0,
        approach_decay: float = 0.7,
        approach_log_odds: float = 2.0,
    ) -> None:
        if min(accel_noise_mps2, bearing_sigma_deg, distance_sigma_frac, distance_sigma_min_m) <= 0:
            raise ValueError("noise levels must be > 0")
        if gate_chi2 <= 0 or max_misses < 1 or lost_after_s <= 0 or min_fixes < 2:
            raise ValueError("gate_chi2 and lost_after_s must be > 0, max_misses >= 1, min_fixes >= 2")
        self.accel_noise_mps2 = accel_noise_mps2
        self.bearing_sigma_deg = bearing_sigma_deg
        self.distance_sigma_frac = distance_sigma_frac
        self.distance_sigma_min_m = distance_sigma_min_m
        self.initial_speed_sigma_mps = initial_speed_sigma_mps
        self.gate_chi2 = gate_chi2
        self.max_misses = max_misses
        self.lost_after_s = lost_after_s
        self.min_fixes = min_fixes
        self.min_speed_mps = min_speed_mps
        self.max_speed_sigma_mps = max_speed_sigma_mps
        if far_m <= 0 or not 0.0 <= approach_decay < 1.0 or approach_log_odds <= 0:
            raise ValueError("far_m and approach_log_odds must be > 0, approach_decay in [0, 1)")
        self.far_m = far_m
        self.near_after = max(1, int(near_after))
        self.crossing_flip_fixes = max(1, int(crossing_flip_fixes))
        self.quiet_siren_db_1m = quiet_siren_db_1m
        self.approach_decay = approach_decay
        self.approach_log_odds = approach_log_odds
        self.reset()

    def reset(self) -> SirenTrackFusion:
        """Forget the track."""
        self.state_: np.ndarray | None = None  # x, y, vx, vy (world)
        self.cov_: np.ndarray | None = None
        self.time_s_ = -math.inf
        self.last_fix_s_ = -math.inf
        self.fixes_ = 0
        self.misses_ = 0
        self.approach_evidence_ = 0.0
        self.approaching_: bool | None = None  # the call the belief gave last
        self.listened_: bool | None = None  # the listener's calls, filtered
        self.crossing_: bool | None = None  # the crossing EV's call
        self.known_relation_ = EVRelation.UNKNOWN
        self.placed_ = False
        self.near_fixes_ = 0
        self.flip_votes_ = 0
        self.held_relation_ = EVRelation.UNKNOWN
        return self

    # --------------------------------------------------------------------------------- filter

    def _fix(
        self, obs: SirenObservation, ego_x: float, ego_y: float, ego_yaw: float
    ) -> tuple[np.ndarray, np.ndarray]:
        src = obs.sources[0]
        assert src.distance_m is not None
        d = max(float(src.distance_m), 1.0)
        phi = ego_yaw + src.bearing_rad
        z = np.array([ego_x + d * math.cos(phi), ego_y + d * math.sin(phi)])
        rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
        s_r = (
            d
            if d >= self.far_m
            else range_sigma_m(d, src.distance_sigma, self.distance_sigma_frac, self.distance_sigma_min_m)
        )
        s_t = d * math.radians(self.bearing_sigma_deg)
        return z, rot @ np.diag([s_r**2, s_t**2]) @ rot.T

    def _predict(self, time_s: float) -> None:
        assert self.state_ is not None and self.cov_ is not None
        dt = max(0.0, time_s - self.time_s_)
        self.state_, self.cov_ = cv_predict(self.state_, self.cov_, dt, self.accel_noise_mps2)
        self.time_s_ = time_s

    def _start(self, time_s: float, z: np.ndarray, r: np.ndarray) -> None:
        self.state_ = np.array([z[0], z[1], 0.0, 0.0])
        cov = np.zeros((4, 4))
        cov[:2, :2] = r
        cov[2, 2] = cov[3, 3] = self.initial_speed_sigma_mps**2
        self.cov_ = cov
        self.time_s_ = self.last_fix_s_ = time_s
        self.fixes_, self.misses_ = 1, 0

    def _correct(self, time_s: float, z: np.ndarray, r: np.ndarray) -> None:
        assert self.state_ is not None and self.cov_ is not None
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 1] = 1.0
        innov = z - h @ self.state_
        s = h @ self.cov_ @ h.T + r
        if float(innov @ np.linalg.solve(s, innov)) > self.gate_chi2:
            self.misses_ += 1
            if self.misses_ >= self.max_misses:
                self._start(time_s, z, r)
            return
        gain = self.cov_ @ h.T @ np.linalg.inv(s)
        self.state_ = self.state_ + gain @ innov
        joseph = np.eye(4) - gain @ h
        self.cov_ = joseph @ self.cov_ @ joseph.T + gain @ r @ gain.T
        self.last_fix_s_ = time_s
        self.fixes_ += 1
        self.misses_ = 0

    # ---------------------------------------------------------------------------------- update

    def update(self, obs: SirenObservation, ego_x: float, ego_y: float, ego_yaw: float) -> EVBelief:
        """Fold in one listener observation (at ``obs.t_end``) with the ego pose then; return the
        belief (module docstring)."""
        t = float(obs.t_end)
        if self.state_ is not None:
            if t - self.last_fix_s_ > self.lost_after_s:
                self.reset()
            else:
                self._predict(t)
        if not obs.is_siren or not obs.sources:
            return EVBelief.nothing(t, source=SOURCE)
        # a degraded array (the listener distrusted capsules): same fix, less confidence, and say so
        trust = obs.health.trust if obs.health is not None else 1.0
        faults = obs.health.faults() if obs.health is not None else ()
        src = obs.sources[0]
        if src.distance_m is None:  # a bearing only: heard, not placed
            return EVBelief(
                time_s=t,
                detected=True,
                confidence=float(obs.smoothed_probability) * trust,
                relation=EVRelation.UNKNOWN,
                bearing_rad=float(src.bearing_rad),
                approaching=src.approaching,
                siren=True,
                source=SOURCE,
                sensor_faults=faults,
            )
        z, r = self._fix(obs, ego_x, ego_y, ego_yaw)
        if self.state_ is None:
            self._start(t, z, r)
        else:
            self._correct(t, z, r)
        assert self.state_ is not None
        x, y, vx, vy = (float(v) for v in self.state_)
        rel_x, rel_y = (float(v) for v in to_vehicle_frame(x - ego_x, y - ego_y, ego_yaw))
        told = self.relation(rel_x, rel_y, ego_yaw)
        if told is not EVRelation.UNKNOWN:
            self.known_relation_ = told  # a track that could tell once keeps it while it cannot
        far = self._is_far(float(src.distance_m), obs.level_db_spl, src.far_probability)
        self.near_fixes_ = 0 if far else self.near_fixes_ + 1
        near = self.near_fixes_ >= (self.near_after if self.placed_ else 1)
        if near:
            self.placed_ = True
            self._listen_approach(src.approaching, src.approach_probability)
            relation = self.held_relation_ = self.known_relation_
        elif self.placed_:  # was placed in range: keep what was known then
            relation = self.held_relation_
        else:  # never in range: what the track alone tells
            relation = self.known_relation_
        approaching: bool | None
        if relation is EVRelation.CROSSING:  # closing in on our road: its offset across it shrinks
            v_across = float(to_vehicle_frame(vx, vy, ego_yaw)[1])
            approaching = self._crossing_approach(bool(rel_y * v_across < 0.0))
        elif near:
            approaching = self.listened_
        else:  # far: the last call made
            approaching = self.approaching_
        self.approaching_ = approaching
        nan = float("nan")
        return EVBelief(
            time_s=t,
            detected=True,
            confidence=float(obs.smoothed_probability) * trust,
            relation=relation,
            rel_x_m=nan if far else rel_x,
            rel_y_m=nan if far else rel_y,
            distance_m=nan if far else math.hypot(rel_x, rel_y),
            bearing_rad=math.atan2(rel_y, rel_x),
            approaching=approaching,
            siren=True,
            source=SOURCE,
            sensor_faults=faults,
        )

    def _is_far(
        self, distance_m: float, level_db_spl: float | None, far_probability: float | None = None
    ) -> bool:
        """A fix beyond ranging: the networks' distance at ``far_m`` or more, a far ranger's far
        probability at :data:`~makeway.perceive.audio.far_range.FAR_CALL_PROBABILITY` or more, or a
        level so low that even the quietest siren (``quiet_siren_db_1m``) would be ``far_m`` away."""
        if distance_m >= self.far_m:
            return True
        if far_probability is not None and far_probability >= FAR_CALL_PROBABILITY:
            return True
        if level_db_spl is None:
            return False
        return 10.0 ** ((self.quiet_siren_db_1m - level_db_spl) / 20.0) >= self.far_m

    def _crossing_approach(self, closing: bool) -> bool:
        """The crossing EV's call: taken at once when there is none yet, changed only after
        ``crossing_flip_fixes`` fixes in a row say otherwise (a far track's heading wobbles)."""
        if self.crossing_ is None or closing == self.crossing_:
            self.crossing_, self.flip_votes_ = closing, 0
        else:
            self.flip_votes_ += 1
            if self.flip_votes_ >= self.crossing_flip_fixes:
                self.crossing_, self.flip_votes_ = closing, 0
        return self.crossing_

    def _listen_approach(self, approaching: bool | None, probability: float | None) -> None:
        """Fold the listener's call into the approach filter (module docstring)."""
        if probability is None:  # an estimator without a probability: its call as it is
            if approaching is not None:
                self.listened_ = approaching
            return
        p = min(max(float(probability), 0.01), 0.99)
        self.approach_evidence_ = self.approach_decay * self.approach_evidence_ + math.log(p / (1.0 - p))
        if self.approach_evidence_ >= self.approach_log_odds:
            self.listened_ = True
        elif self.approach_evidence_ <= -self.approach_log_odds:
            self.listened_ = False

    def relation(self, rel_x: float, rel_y: float, ego_yaw: float) -> EVRelation:
        """The track's relation to the ego, ``UNKNOWN`` while its heading is not known (module
        docstring)."""
        if self.state_ is None or self.cov_ is None or self.fixes_ < self.min_fixes:
            return EVRelation.UNKNOWN
        vx, vy = float(self.state_[2]), float(self.state_[3])
        speed_sigma = math.sqrt(0.5 * float(self.cov_[2, 2] + self.cov_[3, 3]))
        if math.hypot(vx, vy) < self.min_speed_mps or speed_sigma > self.max_speed_sigma_mps:
            return EVRelation.UNKNOWN
        return classify_relation(rel_x, rel_y, math.atan2(vy, vx) - ego_yaw)

    @property
    def velocity_mps(self) -> tuple[float, float] | None:
        """The track's world velocity ``(v_x, v_y)``, ``None`` without a track."""
        if self.state_ is None:
            return None
        return float(self.state_[2]), float(self.state_[3])
