"""The yield decision: a state machine that makes the car give way to an active emergency vehicle (SPEC §6).

The law it serves (Texas Transportation Code 545.156): on an emergency vehicle (EV) using audible and
visual signals, yield the right of way, drive immediately to a position parallel to and as close as
possible to the right-hand edge, clear of any intersection, and stop until the EV has passed.

:class:`YieldStateMachine` consumes the fused :class:`~makeway.messages.EVBelief` of each EV, the ego
:class:`~makeway.messages.VehicleState` and the map's :class:`~makeway.messages.RoadContext` per
decision period and returns a :class:`~makeway.messages.YieldDecision`. Its clock is the later of
``ego.time_s`` and ``belief.time_s`` (it must not go backwards; equal times are fine).

States::

    NO_EV ──confirm──▶ EV_CONFIRMED ──needs yield──▶ MOVING_OVER ──stopped──▶ STOPPED_WAITING
      ▲                 │ (follow / continue                                           │
      │◀──EV gone───────┘  while no yield is needed)                          EV passed │
      │                                                                                ▼
      └──back at speed / timeout── RESUMING ◀──passed_hold_s── EV_PASSED ◀─────────────┘
       (an EV needing a yield, confirmed during EV_PASSED or RESUMING → EV_CONFIRMED)

**Perceiving an EV.** Per belief: *seen* = ``detected`` and ``confidence >= release_confidence``;
*active* = seen, within ``max_relevant_distance_m`` (an unknown distance counts as within; an EV
announced by a verified V2X alert counts up to the duty's ``v2x_horizon_m``), showing lights **or**
siren (an EV that switches its siren off but keeps its lights on is still active;
``signals_required=False`` drops the signal test for producers that do not report them), and with
evidence the duty to yield does not ignore;
*strong* = active with ``confidence >= confirm_confidence``. Confirmation (hysteresis on) needs strong
beliefs without a break for ``confirm_time_s``, so a single-frame spike confirms nothing; a belief
two independent senses support (siren and lights of one fused track) waits only
``corroborated_confirm_time_s`` (default 0), counted from the first strong belief: the fusion's
own confirmation of such a track already is the persistence test. Once
confirmed, the EV is released (hysteresis off) only by the rules below: a dip under
``confirm_confidence`` changes nothing, a gap (not seen) shorter than ``dropout_timeout_s`` changes
nothing.

**Approaching.** ``belief.approaching`` when given; when ``None``, the sign of the change of
``distance_m`` since the previous seen belief; ``None`` (unknown) when neither is available.

**Decision table** (while an EV is confirmed; *approaching* as above, "unknown" = ``None``):

=================  ==========================  ==============================  ==========================
relation           approaching                 action                          why
=================  ==========================  ==============================  ==========================
BEHIND             yes / unknown               ``pull_over_and_stop``          it comes up behind us: the
                                                                               law's case
BEHIND             no (falling back)           ``continue`` (no yield yet)     it is not closing in; yield
                                                                               once it does
AHEAD              no / unknown                ``follow``: target speed ≤      it drives away in front:
                                               current, no pull-over           do not overtake it
AHEAD              yes (stopped, slower,       ``pull_over_and_stop``          it closes in on us: treat
                   reversing)                                                  like BEHIND
ONCOMING           yes / unknown               ``pull_over_and_stop``          the law asks it for any
                                                                               approaching EV (undivided
                                                                               road; ``yield_to_oncoming``
                                                                               =False for divided ones)
ONCOMING           no                          ``continue``                    it has gone by
CROSSING           yes / unknown               ``stop_before_intersection``    never enter the
                                               (stop at start − margin; pull   intersection it heads for
                                               over only with room for it)
CROSSING, ego      yes / unknown               ``clear_intersection``, then    never stop inside an
inside the box                                 pull over and stop after it     intersection
CROSSING           no                          ``continue``                    it has crossed / gone
CROSSING, every    yes / unknown               ``continue``                    its road crosses ours
intersection of                                                                behind the car (a map
the map behind                                                                 with none: the rows above)
the ego
UNKNOWN (heard,    yes / unknown               ``pull_over_and_stop``          conservative: the siren
not placed)                                                                    is real, its place is not
UNKNOWN            no                          ``continue`` (``prepare`` with  a receding siren (its way
                                               an intersection ahead within    unknown: not towards an
                                               ``max_relevant_distance_m``)    intersection at speed)
=================  ==========================  ==============================  ==========================

**The duty to yield** (``YieldConfig.duty``, :mod:`makeway.decide.duty`): the table's yields apply
to an EV whose evidence carries the duty ``"yield"`` (default: siren and lights, a verified V2X
alert, lights alone, or a siren alone that is close and approaching). One whose evidence only
carries ``"prepare"`` (default: a siren alone, far or not placed) gets ``prepare`` instead: keep the
lane at ``prepare_speed_fraction`` of the speed limit until the evidence grows to a yield.

**Not into an intersection with a siren coming.** A siren the duty only prepares for (heard, not
seen), heard approaching (``belief.approaching`` True: the siren stack's call or the track's range
rate; without a break for at least ``unplaced_siren_heard_s``, below) while its way is
unknown (relation UNKNOWN: not placed, or placed where no road relation fits) or crosses ours
(CROSSING), is a yield once the car reaches its decision point for the intersection ahead:
``decide_ahead_s`` of travel before the last point where it can still stop comfortably
(:func:`firm_stop_distance_m` at ``comfort_decel_mps2``, after ``reaction_time_s``, from the
deceleration it already has) ``intersection_margin_m`` before it. The car then stops before the
intersection (firmly if comfort can no longer make it, below), as a driver who hears a siren coming
but cannot yet tell from where does not drive into the crossing; before that point it only
prepares, so a siren that is placed or seen by then is yielded to as what it is
(``stop_for_unplaced_siren=False`` turns this off). A map with no intersection ahead leaves the duty
as it is. The stop waits for a call that has lasted ``unplaced_siren_heard_s`` (default 2 s; 0: the
confirmation alone); until then the car at its decision point brakes towards the stop
(``prepare`` carrying the stop point, ``hold_short_while_heard``), so a call that stops early (street
noise taken for a siren) costs a slow-down and one that lasts finds the car still able to stop.

**Several EVs** (:meth:`YieldStateMachine.update_all`, one belief per EV track): the machine follows
one EV — one that needs a yield first, the one it followed last time next, then the nearest — and
does not leave STOPPED_WAITING while any other EV still needs a yield: it yields until every EV
that requires it has passed. A change of the followed EV (its ``track_id``) clears what was learnt
about the last one's distance and side.

By state: NO_EV ``continue`` at the speed limit; EV_CONFIRMED the table (the confirming decision
already starts the manoeuvre; ``prepare`` under the duty above); MOVING_OVER the table's
manoeuvre with a latched stop point; STOPPED_WAITING and EV_PASSED ``wait`` at 0 m/s; RESUMING
``resume`` at ``resume_speed_mps`` (default: the speed limit).

**Stop point** (``stop_s_m``, arc length along the ego path, same frame as ``RoadContext.s_m``),
chosen once when the manoeuvre starts and kept (re-chosen only when the EV changes from crossing to
same-road or back, or when the ego finds itself inside an intersection short of it; a new EV
confirmed while we still wait in EV_PASSED keeps the stop point we are standing at):

* pull over: ``s + v·reaction_time_s + max(v²/(2·comfort_decel), lane-change length)``, the
  lane-change length being that of a quintic lateral move to ``right_edge_offset_m`` with peak lateral
  acceleration ``max_lat_accel_mps2`` at ``max(v, lane_change_min_speed_mps)``;
* crossing: ``start − intersection_margin_m`` of the first intersection not behind the ego;
* then :func:`clear_stop_point` moves it out of every intersection (widened by the margins): before
  the intersection when the ego can stop there at ``comfort_decel_mps2`` (with the full margin, or at
  least ``intersection_min_margin_m`` before the start), otherwise after its end;
* a stop point beyond an intersection the ego still has to cross is put at least a lane-change
  length past that intersection (plus the exit margin), so the car crosses in its lane
  (``clear_intersection``, no pull-over) and then has room to move over. When the stop point lies
  before an intersection without room for the lane change, the car stops in its lane
  (``stop_before_intersection``, ``pull_over=False``).

An ego inside an intersection always gets a stop point past it and a target speed above zero until
it has cleared it; it never stops inside one.

**A firm stop before an intersection.** For an EV on a crossing road, or one not yet placed (heard,
its relation unknown), the plan is that of a crossing EV when the pull-over would reach an
intersection (its start within the pull-over distance plus a lane-change length), or, for one not
yet placed but heard or seen ahead of abeam, when the intersection is within
``max_relevant_distance_m``: stop before it (such an EV can only meet us through that intersection
or on our road ahead; a pull-over that happens to end short of the intersection would leave the stop
to chance). Comfort is tried first: the stop must lie ``firm_min_margin_m`` or more before the
intersection and be reachable at ``comfort_decel_mps2`` built up at ``comfort_jerk_mps3`` after
``reaction_time_s`` (:func:`firm_stop_distance_m`, from the deceleration the car already has). When
it is not, the stop may be **firm**: at ``max(start − intersection_margin_m, s + firm reach)`` with
the firm reach at ``firm_decel_mps2`` (4.5 m/s²) and ``firm_jerk_mps3``, if that is still
``firm_min_margin_m`` before the intersection; the decision then carries ``max_decel_mps2`` /
``max_jerk_mps3`` for the longitudinal controller (that stop only: every other decision leaves them
``None``, comfort). Otherwise the car clears the intersection first, as a comfort plan does. A
re-plan (the EV placed differently) never turns a stop before an intersection into crossing it, and
keeps it unless the new plan must stop more than ``arrive_tolerance_m`` sooner.

Target speed while moving over: ``min(speed limit, √(2·comfort_decel·(stop − s)), max(v, creep))`` —
never faster than now (except creeping up to the stop point), zero at the stop point.

**Leaving the yield** (STOPPED_WAITING → EV_PASSED), first rule that holds:

1. the EV has gone by: AHEAD and more than ``passed_margin_m`` ahead and receding (an EV from
   behind overtook us; a track never placed behind the car nor within ``close_distance_m`` of it
   must also have got ``far_passed_gain_m`` farther since it first read so, or read so for
   ``far_passed_hold_s`` in a row: a siren beyond the rangers' reach is placed 45–60 m away
   whatever its distance, so an oncoming EV still far ahead reads as pulling away while the car
   closes on it);
   ONCOMING and receding; BEHIND, receding, more than ``passed_margin_m``
   behind after its track was seen more than ``passed_margin_m`` ahead (an oncoming EV went by; seen
   while another EV was followed counts too), or was first placed less than ``abeam_m`` behind
   the car (a track that fusion starts anew as the EV passes close beside the car, where its
   bearing sweeps too fast for the old track to follow); CROSSING or UNKNOWN and receding;
2. lost (not seen) for longer than ``dropout_timeout_s`` with its last known distance within
   ``close_distance_m`` (it went past, out of the sensors' view);
3. no *active* EV for ``siren_off_hold_s``: it switched lights and siren off (it may still pass, so we
   keep yielding that long), or it was lost far away, or it went out of ``max_relevant_distance_m``.

An EV that passes (by these rules) while we are still moving over is noted, and the stop is
completed all the same — the car is half-way to the edge, and a second EV often follows — so the
sequence is always MOVING_OVER → STOPPED_WAITING → EV_PASSED. The car reaches STOPPED_WAITING when
its speed is under ``stopped_speed_mps`` within ``arrive_tolerance_m`` of the stop point (or stuck
short of it for ``stuck_timeout_s``), never while inside an intersection. EV_PASSED lasts
``passed_hold_s``; RESUMING ends (NO_EV) when the speed is back to ``resumed_speed_fraction`` of the
resume speed or after ``resume_timeout_s``. A confirmed EV that needs a yield during EV_PASSED or
RESUMING goes back to EV_CONFIRMED.

Every transition is appended to :attr:`YieldStateMachine.history` as ``(time, from, to, reason)``.

    fsm = YieldStateMachine()
    decision = fsm.update(belief, ego_state, road_context)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, fields

from makeway.decide.duty import DutyToYield, duty_of
from makeway.messages import EVBelief, EVRelation, RoadContext, VehicleState, YieldDecision, YieldState

__all__ = [
    "YieldConfig",
    "YieldStateMachine",
    "clear_stop_point",
    "firm_stop_distance_m",
    "lane_change_length_m",
    "needs_yield",
]

_EPS = 1e-9
# peak of the quintic smoothstep's second derivative, d''(u) = offset · 10/√3 at u = (3 − √3)/6
_QUINTIC_PEAK = 10.0 / math.sqrt(3.0)


@dataclass(frozen=True)
class YieldConfig:
    """Thresholds and timings of :class:`YieldStateMachine` (the module docstring says how each acts).

    Perception and hysteresis:
        confirm_confidence: belief confidence needed, without a break for ``confirm_time_s``, to
            confirm an EV (hysteresis on).
        confirm_time_s: how long the confidence must stay at or above ``confirm_confidence``.
        corroborated_confirm_time_s: the same for a belief that two independent senses support
            (two of ``sources``: siren and lights of one track, or a sense and a verified alert;
            or a siren whose track showed lights within the duty's ``lights_memory_s``).
            Default 0: the fusion confirmed such a track only after several scans in a row with
            both senses on one bearing, and holds each sense for a second
            (:data:`~makeway.fuse.multi_ev.SENSE_HOLD_S`), so the belief cannot be a one-frame
            spike and a further wait only delays the yield. Beliefs with one sense, or none
            named (the modelled perception), keep ``confirm_time_s``.
        release_confidence: below this a belief counts as "EV not seen" (hysteresis off).
        dropout_timeout_s: gaps in perception shorter than this change nothing.
        siren_off_hold_s: with no active EV (lights and siren off, or lost far away) keep yielding this
            long before resuming: it may still pass.
        max_relevant_distance_m: an EV farther than this is not acted on.
        signals_required: an EV counts as active only with lights or siren perceived.
        yield_to_oncoming: pull over for an approaching oncoming EV (undivided roads; set ``False``
            for a divided one).

    Passing and resuming:
        passed_hold_s: wait this long after the EV passed before resuming.
        close_distance_m: an EV lost for longer than ``dropout_timeout_s`` within this distance is
            taken to have passed.
        passed_margin_m: an EV that went by must be this far ahead (or behind) and receding.
        abeam_m: a track first placed less than this far behind the car (level with it, or ahead)
            counts as one that came from level or ahead: once behind and receding it has gone by.
        far_passed_gain_m: an EV ahead and receding whose track was never placed behind the car
            nor within ``close_distance_m`` of it counts as passed only once its distance has
            grown by this much since it first read so (it may be an oncoming EV whose siren is
            placed too near: such a track stays within the siren rangers' 45–60 m) …
        far_passed_hold_s: … or after reading so for this long without a break.
        resume_speed_mps: the speed to get back to (default ``None``: the road's speed limit).
        resumed_speed_fraction: RESUMING ends at this fraction of the resume speed.
        resume_timeout_s: RESUMING ends at the latest after this long.

    Manoeuvre:
        stopped_speed_mps: below this the ego counts as stopped.
        comfort_decel_mps2: the deceleration stops are planned with.
        max_lat_accel_mps2: peak lateral acceleration of the lane change to the right edge.
        lane_change_min_speed_mps: lane changes are sized at no less than this speed.
        reaction_time_s: the manoeuvre starts this long after the decision (actuation delay).
        creep_speed_mps: a (nearly) stopped ego may creep up to its stop point at this speed.
        intersection_margin_m: gap between a stop point and an intersection's start; the stop point
            is the ego's reference point (rear axle), so this covers the front of the car.
        intersection_min_margin_m: the smallest such gap accepted when the full one cannot be
            reached at ``comfort_decel_mps2`` (the ego is already close to the intersection).
        intersection_exit_margin_m: how far past an intersection's end a stop point must be.
        firm_decel_mps2: the deceleration (m/s²) a **firm stop** before an intersection may use
            when the comfortable one cannot stop short of it and the EV heads for it (crossing) or
            is not yet placed (module docstring, "A firm stop"). Default 4.5 m/s² (0.46 g): above
            the comfort limit, clearly below emergency braking (8–9 m/s² on dry asphalt) and below
            the grip of a wet road (μ ≈ 0.5: 4.9 m/s²). Set it to ``comfort_decel_mps2`` to never
            brake harder than comfort.
        comfort_jerk_mps3: the jerk (m/s³) the longitudinal controller builds a comfortable
            deceleration with (its ``max_jerk``): a stop before an intersection counts as within
            comfort only when :func:`firm_stop_distance_m` at ``comfort_decel_mps2`` and this jerk,
            after ``reaction_time_s``, reaches it.
        firm_jerk_mps3: the jerk (m/s³) a firm stop builds its deceleration with.
        firm_min_margin_m: the smallest gap between a firm stop point and the intersection's start
            (the stop point is the car's centre: half its length plus what a firm stop may run
            past its point).
        pull_over_before_intersection: for a crossing EV, also move to the right edge when there is
            room before the intersection (``False``: stop in lane).
        stop_for_unplaced_siren: a siren the duty only prepares for, heard approaching while its way
            is unknown (not placed) or crosses ours, stops the car before the intersection ahead
            once it must decide (module docstring, "Not into an intersection").
        unplaced_siren_heard_s: how long (s) such a siren must have been heard approaching, without
            a break (its track absent or its call not "approaching" for one period restarts the
            clock), before it stops the car; 0: its confirmation alone. Street noise taken for a
            siren gives approaching calls of 0.85–1.7 s (the false stops of the no-EV drives
            through crossroads, docs/results.md): 2 s (default) removes them, and with
            ``hold_short_while_heard`` a siren first heard ~40 m from the car still finds it able
            to stop (without it, 2 s lets two crossing seeds of forty drive into the intersection).
        hold_short_while_heard: while such a siren's call has not yet lasted
            ``unplaced_siren_heard_s`` and the car is at its decision point, brake towards a stop
            before the intersection (``prepare`` with that stop point; firm limits where comfort
            can no longer make it) instead of
            driving on: a call that lasts then stops the car as if it had not waited, one that stops
            costs a slow-down, not a stop. No effect when ``unplaced_siren_heard_s`` is 0.
        decide_ahead_s: how many seconds of travel before the last point where a comfortable stop
            before the intersection is still possible the car decides to stop for such a siren.
        arrive_tolerance_m: stopped within this distance of the stop point counts as arrived.
        stuck_timeout_s: stopped short of the stop point for this long counts as arrived too.

    The law:
        duty: which evidence obliges a yield (:class:`~makeway.decide.duty.DutyToYield`; default the
            "audible and visual" rule; presets in :data:`~makeway.decide.duty.DUTY_PRESETS`).
    """

    confirm_confidence: float = 0.6
    confirm_time_s: float = 0.3
    corroborated_confirm_time_s: float = 0.0
    release_confidence: float = 0.3
    dropout_timeout_s: float = 2.0
    siren_off_hold_s: float = 5.0
    passed_hold_s: float = 2.0
    stopped_speed_mps: float = 0.2
    resume_speed_mps: float | None = None
    max_relevant_distance_m: float = 150.0
    signals_required: bool = True
    yield_to_oncoming: bool = True
    close_distance_m: float = 30.0
    passed_margin_m: float = 10.0
    abeam_m: float = 5.0
    far_passed_gain_m: float = 20.0
    far_passed_hold_s: float = 6.0
    resumed_speed_fraction: float = 0.9
    resume_timeout_s: float = 20.0
    comfort_decel_mps2: float = 3.0
    max_lat_accel_mps2: float = 1.5
    lane_change_min_speed_mps: float = 5.0
    reaction_time_s: float = 0.2
    creep_speed_mps: float = 3.0
    intersection_margin_m: float = 5.0
    intersection_min_margin_m: float = 1.0
    intersection_exit_margin_m: float = 5.0
    comfort_jerk_mps3: float = 2.5
    firm_decel_mps2: float = 4.5
    firm_jerk_mps3: float = 8.0
    firm_min_margin_m: float = 3.0
    pull_over_before_intersection: bool = True
    stop_for_unplaced_siren: bool = True
    unplaced_siren_heard_s: float = 2.0
    hold_short_while_heard: bool = True
    decide_ahead_s: float = 1.0
    arrive_tolerance_m: float = 3.0
    stuck_timeout_s: float = 3.0
    duty: DutyToYield = field(default_factory=DutyToYield)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or value is None or not isinstance(value, (int, float)):
                continue
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"YieldConfig.{f.name} must be finite and >= 0, got {value}")
        if not 0.0 <= self.release_confidence <= self.confirm_confidence <= 1.0:
            raise ValueError(
                "need 0 <= release_confidence <= confirm_confidence <= 1, got "
                f"{self.release_confidence} and {self.confirm_confidence}"
            )
        if self.comfort_decel_mps2 <= 0.0 or self.max_lat_accel_mps2 <= 0.0:
            raise ValueError("comfort_decel_mps2 and max_lat_accel_mps2 must be > 0")
        if not 0.0 < self.resumed_speed_fraction <= 1.0:
            raise ValueError(f"resumed_speed_fraction must lie in (0, 1], got {self.resumed_speed_fraction}")
        if self.intersection_min_margin_m > self.intersection_margin_m:
            raise ValueError("intersection_min_margin_m must not exceed intersection_margin_m")
        if self.firm_decel_mps2 < self.comfort_decel_mps2 or self.firm_jerk_mps3 <= 0.0:
            raise ValueError("firm_decel_mps2 must be >= comfort_decel_mps2 and firm_jerk_mps3 > 0")


# ------------------------------------------------------------------------------------ pure helpers


def needs_yield(relation: EVRelation, approaching: bool | None, *, yield_to_oncoming: bool = True) -> bool:
    """Whether an active EV in ``relation`` asks us to pull over / stop (the module's decision table).

    ``approaching`` is ``None`` when unknown; unknown counts as approaching except for an EV ahead
    (which by default drives away from us).
    """
    if relation is EVRelation.AHEAD:
        return approaching is True
    if relation is EVRelation.ONCOMING:
        return yield_to_oncoming and approaching is not False
    return approaching is not False  # BEHIND, CROSSING, UNKNOWN


def lane_change_length_m(
    speed_mps: float, offset_m: float, max_lat_accel_mps2: float, min_speed_mps: float = 0.0
) -> float:
    """Length of a quintic-smoothstep lateral move by ``offset_m`` at ``speed_mps`` whose peak lateral
    acceleration is ``max_lat_accel_mps2``: ``L = v·√(10·|offset| / (√3·a_lat))`` with
    ``v = max(speed, min_speed)``."""
    if max_lat_accel_mps2 <= 0.0:
        raise ValueError(f"max_lat_accel_mps2 must be > 0, got {max_lat_accel_mps2}")
    v = max(speed_mps, min_speed_mps, 0.0)
    return v * math.sqrt(_QUINTIC_PEAK * abs(offset_m) / max_lat_accel_mps2)


def firm_stop_distance_m(
    speed_mps: float, decel_mps2: float, jerk_mps3: float, delay_s: float, current_decel_mps2: float = 0.0
) -> float:
    """Distance (m) a car at ``speed_mps``, already braking at ``current_decel_mps2`` (≥ 0), needs to
    stop when it keeps that deceleration for ``delay_s`` (the actuation delay), then builds it up to
    ``decel_mps2`` at ``jerk_mps3`` and holds it to a stop (constant-jerk ramp, then constant
    deceleration; each phase ends early if the car is already at rest)."""
    if decel_mps2 <= 0.0 or jerk_mps3 <= 0.0:
        raise ValueError(f"decel and jerk must be > 0, got {decel_mps2}, {jerk_mps3}")
    v = max(float(speed_mps), 0.0)
    a0 = min(max(float(current_decel_mps2), 0.0), decel_mps2)
    delay = max(float(delay_s), 0.0)
    if a0 > 0.0 and v <= a0 * delay:
        return v * v / (2.0 * a0)
    dist = v * delay - 0.5 * a0 * delay * delay
    v -= a0 * delay
    ramp = (decel_mps2 - a0) / jerk_mps3
    lost = 0.5 * (a0 + decel_mps2) * ramp
    if lost >= v:  # at rest during the ramp: step the ramp finely
        n = 100
        h = ramp / n
        a = a0
        for _ in range(n):
            if v <= 0.0:
                break
            dist += max(v * h - 0.5 * a * h * h, 0.0)
            v -= a * h
            a += jerk_mps3 * h
        return dist
    dist += v * ramp - (0.5 * a0 + (decel_mps2 - a0) / 6.0) * ramp * ramp
    v -= lost
    return dist + v * v / (2.0 * decel_mps2)


def _zones(
    intersections: Iterable[tuple[float, float]], margin_m: float, exit_margin_m: float
) -> list[tuple[float, float, float]]:
    """Intersections widened to ``(start − margin, end + exit_margin)``, sorted and merged; each zone
    also keeps the start of its first intersection."""
    raw = []
    for pair in intersections:
        a, b = float(pair[0]), float(pair[1])
        if not (math.isfinite(a) and math.isfinite(b)) or b < a:
            raise ValueError(f"intersection interval {pair} must be finite with start <= end")
        raw.append((a - margin_m, b + exit_margin_m, a))
    merged: list[tuple[float, float, float]] = []
    for lo, hi, a in sorted(raw):
        if merged and lo <= merged[-1][1]:
            plo, phi, pa = merged[-1]
            merged[-1] = (plo, max(phi, hi), min(pa, a))
        else:
            merged.append((lo, hi, a))
    return merged


def clear_stop_point(
    s_m: float,
    speed_mps: float,
    desired_s_m: float,
    intersections: Iterable[tuple[float, float]],
    *,
    decel_mps2: float = 3.0,
    margin_m: float = 5.0,
    min_margin_m: float = 1.0,
    exit_margin_m: float = 5.0,
) -> float:
    """A stop point at or after ``desired_s_m`` (never closer than the ego can stop at ``decel_mps2``)
    that lies in no intersection.

    Each intersection ``(start, end)`` is a keep-out zone ``(start − margin_m, end + exit_margin_m)``.
    A stop point inside one moves **before** it, to ``start − margin_m``, when the ego (at ``s_m``,
    ``speed_mps``) can stop there at ``decel_mps2``; failing that to the ego's earliest comfortable stop
    if that is still ``min_margin_m`` before ``start``; otherwise **after** it, to
    ``end + exit_margin_m`` (checked again against the intersections further on). An ego inside an
    intersection therefore always gets a stop point past it.
    """
    if decel_mps2 <= 0.0:
        raise ValueError(f"decel_mps2 must be > 0, got {decel_mps2}")
    v = max(float(speed_mps), 0.0)
    floor = float(s_m) + v * v / (2.0 * decel_mps2)  # nothing closer than comfortable braking allows
    stop = max(float(desired_s_m), floor)
    for lo, hi, start in _zones(intersections, margin_m, exit_margin_m):
        if stop <= lo:
            break  # zones are sorted: every later one is further on
        if stop >= hi:
            continue
        if lo >= floor:
            return lo
        if floor <= start - min_margin_m:
            return floor
        stop = floor = hi  # cannot stop before it: clear it first
    return stop


def _containing(s_m: float, intersections: Iterable[tuple[float, float]]) -> tuple[float, float] | None:
    for a, b in intersections:
        if a <= s_m <= b:
            return (float(a), float(b))
    return None


def _finite(x: float) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def _distance(b: EVBelief) -> float:
    if _finite(b.distance_m):
        return float(b.distance_m)
    if _finite(b.rel_x_m) and _finite(b.rel_y_m):
        return math.hypot(b.rel_x_m, b.rel_y_m)
    return math.nan


def _rel_x(b: EVBelief) -> float:
    if _finite(b.rel_x_m):
        return float(b.rel_x_m)
    if _finite(b.distance_m) and _finite(b.bearing_rad):
        return float(b.distance_m) * math.cos(b.bearing_rad)
    return math.nan


_WHERE = {
    EVRelation.BEHIND: "behind",
    EVRelation.AHEAD: "ahead",
    EVRelation.ONCOMING: "oncoming",
    EVRelation.CROSSING: "on a crossing road",
    EVRelation.UNKNOWN: "not yet placed",
}


def _describe(b: EVBelief | None, approaching: bool | None) -> str:
    """``"emergency vehicle behind (42 m away, approaching)"`` (no article)."""
    if b is None:
        return "emergency vehicle"
    d = _distance(b)
    details = [f"{d:.0f} m away"] if _finite(d) else []
    if approaching is not None:
        details.append("approaching" if approaching else "moving away")
    text = f"emergency vehicle {_WHERE.get(b.relation, str(b.relation))}"
    return f"{text} ({', '.join(details)})" if details else text


@dataclass(frozen=True, slots=True)
class _Plan:
    """The latched manoeuvre: where to stop and whether to move to the right edge on the way."""

    crossing: bool  # planned for a crossing EV (stop before the intersection it heads for)
    stop_s_m: float
    pull_over_ok: bool  # room to move over before the stop point
    before_intersection: bool  # the stop point is just before an intersection
    firm: bool = False  # a firm stop: the comfortable deceleration cannot make it
    unknown_way: bool = False  # stop before the intersection for an EV ahead of abeam, not placed


# ---------------------------------------------------------------------------------- state machine


class YieldStateMachine:
    """Decides, each period, how to give way to an emergency vehicle (see the module docstring).

    Args:
        config: thresholds and timings (default :class:`YieldConfig`).

    Attributes:
        history: every transition as ``(time_s, from_state, to_state, reason)``.
    """

    def __init__(self, config: YieldConfig | None = None) -> None:
        self.config = config if config is not None else YieldConfig()
        self.history: list[tuple[float, YieldState, YieldState, str]] = []
        self.reset()

    # -------------------------------------------------------------------------------------- public

    @property
    def state(self) -> YieldState:
        """The current state."""
        return self._state

    def reset(self) -> None:
        """Back to NO_EV with no memory of any EV; the history is cleared."""
        self._state = YieldState.NO_EV
        self._entered_s = -math.inf
        self.history.clear()
        self._last_time: float | None = None
        # perception memory
        self._belief: EVBelief | None = None  # the last seen belief
        self._approach: bool | None = None
        self._seen_now = False
        self._last_seen_s = -math.inf
        self._last_active_s = -math.inf
        self._last_distance = math.nan
        self._run_since: float | None = None  # strong beliefs without a break since
        self._corroborated = False  # the followed belief has two independent senses
        self._yield_run_since: float | None = None  # … that also need a yield
        self._ev_was_ahead = False
        # manoeuvre memory
        self._plan: _Plan | None = None
        self._plan_note = ""
        self._stopped_since: float | None = None
        self._passed_note: str | None = None  # the EV passed while we were still moving over
        self._pull_over = False
        self._duty = "ignore"  # the duty the followed EV's evidence carries
        self._others_wanting = False  # another EV than the followed one needs a yield
        self._lights_since: dict[int | None, float] = {}  # per track: lights shown without a break since
        self._lights_seen: dict[int | None, float] = {}  # per track: when it last showed lights
        self._coming_since: dict[int | None, float] = {}  # per track: siren heard approaching since
        self._ahead_tracks: set[int] = set()  # tracks seen more than passed_margin_m ahead, or first
        # placed less than abeam_m behind the car
        self._placed_tracks: set[int] = set()  # tracks placed (a finite rel_x) at least once
        # tracks placed behind the car or within close_distance_m at least once (``None``: beliefs
        # without a track id, forgotten when the car is back to NO_EV)
        self._near_tracks: set[int | None] = set()
        self._far_receding_since: float | None = None  # followed EV ahead and receding since …
        self._far_receding_min_m = math.inf  # … and its least distance since (m)
        self._road_s = 0.0  # the ego's arc length and the map's intersections, this period
        self._boxes: tuple[tuple[float, float], ...] = ()
        self._ego_v = 0.0  # the ego's speed (m/s) and deceleration (m/s², >= 0), this period
        self._ego_brake = 0.0

    def update(self, belief: EVBelief, ego: VehicleState, road: RoadContext) -> YieldDecision:
        """:meth:`update_all` with one belief."""
        return self.update_all([belief], ego, road)

    def update_all(self, beliefs: Sequence[EVBelief], ego: VehicleState, road: RoadContext) -> YieldDecision:
        """Take this period's beliefs (one per EV; at least one, "nothing" beliefs allowed), ego state
        and road; return the decision (stamped "now").

        The state machine follows one EV at a time: of the EVs seen, one whose duty is a yield and
        that needs one (decision table), the one it followed last time first, then the nearest.
        While any other EV still needs a yield the car does not leave STOPPED_WAITING: it yields
        until every EV that requires it has passed.

        "Now" is the later of ``ego.time_s`` and ``belief.time_s``: a belief may be older than the
        vehicle state (perception latency, a message held between measurements).

        Raises:
            ValueError: "now" is earlier than the previous update's.
        """
        if not beliefs:
            raise ValueError("update_all needs at least one belief")
        self._road_s, self._boxes = float(road.s_m), tuple(road.intersections)
        self._ego_v, self._ego_brake = max(float(ego.vx_mps), 0.0), max(-float(ego.ax_mps2), 0.0)
        # per track, lights shown / a siren heard approaching without a break since (a track absent
        # this period is a break too), and when the cameras last saw its lights
        lit = {b.track_id: b.time_s for b in beliefs if b.detected and b.lights}
        self._lights_since = {k: self._lights_since.get(k, t) for k, t in lit.items()}
        coming = {b.track_id: b.time_s for b in beliefs if b.detected and b.siren and b.approaching is True}
        self._coming_since = {k: self._coming_since.get(k, t) for k, t in coming.items()}
        for b in beliefs:
            if b.detected and b.lights and "light" in b.sources:  # the cameras' (not a V2X flag)
                self._lights_seen[b.track_id] = b.time_s
            rel_x = _rel_x(b)
            if b.detected and b.track_id is not None and _finite(rel_x):
                first = b.track_id not in self._placed_tracks
                self._placed_tracks.add(b.track_id)
                if rel_x > self.config.passed_margin_m or (first and rel_x > -self.config.abeam_m):
                    self._ahead_tracks.add(b.track_id)
            near = _finite(rel_x) and (
                rel_x < -self.config.passed_margin_m or _distance(b) <= self.config.close_distance_m
            )
            if b.detected and near:
                self._near_tracks.add(b.track_id)
        if len(self._placed_tracks) > 64:  # forget tracks long gone
            live = {b.track_id for b in beliefs if b.track_id is not None}
            self._ahead_tracks &= live
            self._placed_tracks &= live
            self._near_tracks &= live
        if len(self._lights_seen) > 64:  # forget tracks long gone
            memory = self.config.duty.lights_memory_s
            latest = max(self._lights_seen.values())
            self._lights_seen = {k: v for k, v in self._lights_seen.items() if latest - v <= memory}
        belief = self._choose(beliefs)
        self._others_wanting = any(b is not belief and self._belief_wants(b) for b in beliefs)
        stamps = [float(x) for x in (ego.time_s, belief.time_s) if _finite(x)]
        if not stamps:
            raise ValueError("ego.time_s and belief.time_s are both not finite")
        now = max(stamps)
        if self._last_time is not None and now < self._last_time - _EPS:
            raise ValueError(f"time went backwards: {now} after {self._last_time} (call reset() first)")
        self._last_time = now
        self._observe(belief, now)
        self._step(now, ego, road)
        return self._decide(now, ego, road)

    # ------------------------------------------------------------------------------- perception

    def _duty_for(self, b: EVBelief) -> str:
        """The duty of ``b``'s evidence; a producer that reports no signals (``signals_required``
        off) is taken as showing both."""
        cfg = self.config
        if not (b.lights or b.siren or "v2x" in b.sources or cfg.signals_required):
            return cfg.duty.siren_and_lights if b.detected else "ignore"
        since = self._lights_since.get(b.track_id)
        lights_for = b.time_s - since if since is not None else 0.0
        duty = duty_of(b, cfg.duty, lights_for, self._lights_ago(b))
        if duty == "prepare" and self._must_decide_before_intersection(b):
            return "yield"
        return duty

    def _lights_ago(self, b: EVBelief) -> float:
        """How long ago (s) ``b``'s track last showed lights (inf: never, or no track)."""
        seen = self._lights_seen.get(b.track_id) if b.track_id is not None else None
        return b.time_s - seen if seen is not None else math.inf

    def _two_senses(self, b: EVBelief) -> bool:
        """Whether two independent senses support ``b``: two of its ``sources``, or its siren with
        lights seen on its track within the duty's ``lights_memory_s``."""
        if len(set(b.sources)) >= 2:
            return True
        return b.siren and b.track_id is not None and self._lights_ago(b) <= self.config.duty.lights_memory_s

    def _must_decide_before_intersection(self, b: EVBelief) -> bool:
        """Whether a prepared-for siren makes the car stop before the intersection ahead now (module
        docstring, "Not into an intersection"): heard approaching (for ``unplaced_siren_heard_s``
        without a break), its way unknown or crossing ours, and the car ``decide_ahead_s`` of travel
        from the last point where it can still stop comfortably ``intersection_margin_m`` before
        the intersection."""
        return self._at_unplaced_decision_point(b) and self._heard_long_enough(b)

    def _heard_long_enough(self, b: EVBelief) -> bool:
        """Whether ``b``'s siren has been heard approaching without a break for
        ``unplaced_siren_heard_s`` (always, when that is 0)."""
        wait = self.config.unplaced_siren_heard_s
        if wait <= 0.0:
            return True
        since = self._coming_since.get(b.track_id)
        return since is not None and b.time_s - since >= wait - _EPS

    def _holding_short(self, b: EVBelief | None) -> bool:
        """Whether the car brakes towards a stop before the intersection ahead while ``b``'s call
        has not yet lasted ``unplaced_siren_heard_s`` (module docstring, "Not into an
        intersection"): every other condition of the stop holds."""
        if b is None or self.config.unplaced_siren_heard_s <= 0.0 or not self.config.hold_short_while_heard:
            return False
        return self._at_unplaced_decision_point(b) and not self._heard_long_enough(b)

    def _at_unplaced_decision_point(self, b: EVBelief) -> bool:
        """A siren heard approaching, its way unknown or crossing ours, with the car at or past its
        decision point for the intersection ahead (the time it has heard it aside)."""
        cfg = self.config
        if not (cfg.stop_for_unplaced_siren and b.siren and b.approaching is True):
            return False
        if b.relation not in (EVRelation.UNKNOWN, EVRelation.CROSSING):
            return False
        s, v = self._road_s, self._ego_v
        start = min((float(a) for a, _ in self._boxes if float(a) > s), default=math.inf)
        if not math.isfinite(start):
            return False
        reach = firm_stop_distance_m(
            v, cfg.comfort_decel_mps2, cfg.comfort_jerk_mps3, cfg.reaction_time_s, self._ego_brake
        )
        return start - cfg.intersection_margin_m - s <= reach + v * cfg.decide_ahead_s

    def _relevant(self, b: EVBelief) -> bool:
        dist = _distance(b)
        if not _finite(dist) or dist <= self.config.max_relevant_distance_m:
            return True
        return "v2x" in b.sources and dist <= self.config.duty.v2x_horizon_m

    def _needs(self, relation: EVRelation, approaching: bool | None) -> bool:
        """:func:`needs_yield`, and for an EV on a crossing road an intersection not yet behind the
        ego: with the map's intersections all behind, the crossing road it is on crosses ours behind
        the car, and it needs no yield (a map with none keeps the conservative table)."""
        if not needs_yield(relation, approaching, yield_to_oncoming=self.config.yield_to_oncoming):
            return False
        if relation is not EVRelation.CROSSING or not self._boxes:
            return True
        return any(float(b) >= self._road_s for _, b in self._boxes)

    def _belief_wants(self, b: EVBelief) -> bool:
        """Whether ``b`` alone is a strong, active EV whose duty is a yield and that needs one."""
        cfg = self.config
        conf = float(b.confidence) if _finite(b.confidence) else 0.0
        return (
            bool(b.detected)
            and conf >= cfg.confirm_confidence
            and (b.lights or b.siren or not cfg.signals_required)
            and self._relevant(b)
            and self._duty_for(b) == "yield"
            and self._needs(b.relation, b.approaching)
        )

    def _choose(self, beliefs: Sequence[EVBelief]) -> EVBelief:
        """The belief the state machine follows this period (see :meth:`update_all`)."""
        if len(beliefs) == 1:
            return beliefs[0]
        cfg = self.config
        last = self._belief.track_id if self._belief is not None else None

        def key(b: EVBelief) -> tuple[bool, bool, bool, float]:
            conf = float(b.confidence) if _finite(b.confidence) else 0.0
            seen = bool(b.detected) and conf >= cfg.release_confidence
            d = _distance(b)
            return (not seen, not self._belief_wants(b), b.track_id != last, d if _finite(d) else math.inf)

        return min(beliefs, key=key)

    def _observe(self, b: EVBelief, now: float) -> None:
        cfg = self.config
        conf = float(b.confidence) if _finite(b.confidence) else 0.0
        seen = bool(b.detected) and conf >= cfg.release_confidence
        self._seen_now = seen
        if not seen:
            self._run_since = self._yield_run_since = self._far_receding_since = None
            self._corroborated = False
            return
        if self._belief is not None and b.track_id != self._belief.track_id:
            # another EV: what was learnt about the last one's distance and side does not carry over
            # (but whether this EV's own track was seen ahead, while another was followed, does)
            self._last_distance = math.nan
            self._ev_was_ahead = b.track_id in self._ahead_tracks
            self._far_receding_since = None
        self._duty = self._duty_for(b)
        dist = _distance(b)
        approach = b.approaching
        held = self._belief is not None and self._belief.time_s == b.time_s  # the same message again
        if approach is None and held:
            approach = self._approach
        elif approach is None and _finite(dist) and _finite(self._last_distance):
            change = dist - self._last_distance
            approach = None if abs(change) < 1e-6 else change < 0.0
        self._belief, self._approach, self._last_seen_s = b, approach, now
        if _finite(dist):
            self._last_distance = dist
        rel_x = _rel_x(b)
        if _finite(rel_x) and rel_x > cfg.passed_margin_m:
            self._ev_was_ahead = True
        far_receding = (
            approach is False and self._ahead_past_margin(b) and b.track_id not in self._near_tracks
        )
        if not far_receding:
            self._far_receding_since = None
        elif self._far_receding_since is None:
            self._far_receding_since, self._far_receding_min_m = now, dist if _finite(dist) else math.inf
        elif _finite(dist):
            self._far_receding_min_m = min(self._far_receding_min_m, dist)
        relevant = self._relevant(b)
        signals = b.lights or b.siren or not cfg.signals_required
        active = relevant and signals and self._duty != "ignore"
        if active:
            self._last_active_s = now
        strong = active and conf >= cfg.confirm_confidence
        self._corroborated = strong and self._two_senses(b)
        self._run_since = (self._run_since if self._run_since is not None else now) if strong else None
        wants = strong and self._duty == "yield" and self._needs(b.relation, approach)
        self._yield_run_since = (
            (self._yield_run_since if self._yield_run_since is not None else now) if wants else None
        )

    def _confirmed(self, since: float | None, now: float) -> bool:
        cfg = self.config
        dwell = cfg.corroborated_confirm_time_s if self._corroborated else cfg.confirm_time_s
        return since is not None and now - since >= dwell - _EPS

    def _wants_yield(self) -> bool:
        b = self._belief
        return b is not None and self._duty == "yield" and self._needs(b.relation, self._approach)

    def _prepares(self) -> bool:
        b = self._belief
        return b is not None and self._duty == "prepare" and self._needs(b.relation, self._approach)

    def _gone_reason(self, now: float) -> str | None:
        """Why the EV no longer counts (lost or inactive too long), or ``None``."""
        cfg = self.config
        unseen = now - self._last_seen_s
        inactive = now - self._last_active_s
        if unseen > cfg.dropout_timeout_s:
            return f"the emergency vehicle has not been perceived for {unseen:.1f} s"
        if inactive >= cfg.siren_off_hold_s - _EPS:
            return f"no lights or siren (or out of range) for {inactive:.1f} s"
        return None

    def _ahead_past_margin(self, b: EVBelief) -> bool:
        """``b`` is AHEAD and not known to be within ``passed_margin_m`` ahead."""
        rel_x = _rel_x(b)
        near = _finite(rel_x) and rel_x <= self.config.passed_margin_m
        return b.relation is EVRelation.AHEAD and not near

    def _passed_reason(self, now: float) -> str | None:
        """Why the EV has passed (rules 1–3 of the module docstring), or ``None``."""
        cfg = self.config
        b = self._belief
        if self._seen_now and b is not None and self._approach is False:
            rel_x = _rel_x(b)
            r = b.relation
            gap = f" {abs(rel_x):.0f} m" if _finite(rel_x) else ""
            if self._ahead_past_margin(b):
                if b.track_id in self._near_tracks:
                    return f"the emergency vehicle is{gap} ahead and pulling away: it has passed"
                since = self._far_receding_since
                gain = _distance(b) - self._far_receding_min_m
                if since is not None and _finite(gain) and gain >= cfg.far_passed_gain_m - _EPS:
                    return (
                        f"the emergency vehicle is{gap} ahead and pulling away, {gain:.0f} m farther "
                        f"than {now - since:.1f} s ago: it has passed"
                    )
                if since is not None and now - since >= cfg.far_passed_hold_s - _EPS:
                    return (
                        f"the emergency vehicle is{gap} ahead and has been pulling away for "
                        f"{now - since:.1f} s: it has passed"
                    )
            if r is EVRelation.ONCOMING:
                return "the oncoming emergency vehicle is moving away: it has gone by"
            if (
                r is EVRelation.BEHIND
                and self._ev_was_ahead
                and not (_finite(rel_x) and rel_x >= -cfg.passed_margin_m)
            ):
                return f"the emergency vehicle went by and is{gap} behind, moving away"
            if r in (EVRelation.CROSSING, EVRelation.UNKNOWN):
                return "the emergency vehicle is moving away: it has crossed or gone"
        unseen = now - self._last_seen_s
        if unseen > cfg.dropout_timeout_s and self._last_distance <= cfg.close_distance_m:
            return (
                f"the emergency vehicle was lost {unseen:.1f} s ago "
                f"{self._last_distance:.0f} m away: taken to have passed"
            )
        inactive = now - self._last_active_s
        if inactive >= cfg.siren_off_hold_s - _EPS:
            if self._seen_now:
                return f"the emergency vehicle has shown no lights or siren for {inactive:.1f} s"
            return f"no active emergency vehicle perceived for {inactive:.1f} s"
        return None

    # ------------------------------------------------------------------------------ transitions

    def _go(self, to: YieldState, now: float, reason: str) -> None:
        came_from = self._state
        self.history.append((now, came_from, to, reason))
        self._state = to
        self._entered_s = now
        plan = self._plan
        if to is YieldState.EV_CONFIRMED and came_from is YieldState.EV_PASSED and plan is not None:
            # still stopped clear of intersections at the edge: wait for the new EV right here
            crossing = self._belief is not None and self._belief.relation is EVRelation.CROSSING
            self._plan = _Plan(crossing, plan.stop_s_m, plan.pull_over_ok, plan.before_intersection)
        elif to in (YieldState.EV_CONFIRMED, YieldState.NO_EV, YieldState.RESUMING):
            self._plan = None
        if to is YieldState.EV_CONFIRMED:
            b = self._belief
            rel_x = _rel_x(b) if b is not None and self._seen_now else math.nan
            self._ev_was_ahead = (_finite(rel_x) and rel_x > self.config.passed_margin_m) or (
                b is not None and b.track_id in self._ahead_tracks
            )
        if to is YieldState.MOVING_OVER:
            self._stopped_since = None
            self._passed_note = None
        if to is YieldState.NO_EV:
            self._near_tracks.discard(None)  # the EV without a track id is gone

    def _step(self, now: float, ego: VehicleState, road: RoadContext) -> None:
        cfg = self.config
        st = self._state
        what = _describe(self._belief, self._approach)
        if st is YieldState.NO_EV:
            if self._confirmed(self._run_since, now):
                self._go(YieldState.EV_CONFIRMED, now, f"confirmed an {what}")
        elif st is YieldState.EV_CONFIRMED:
            gone = self._gone_reason(now)
            if gone is not None:
                self._go(YieldState.NO_EV, now, gone)
            elif self._wants_yield():
                self._ensure_plan(ego, road)
                self._go(YieldState.MOVING_OVER, now, f"yielding to the {what}")
        elif st is YieldState.MOVING_OVER:
            # an EV that passes before we are stopped is noted; the stop is completed all the same
            passed = self._passed_reason(now)
            if passed is not None:
                self._passed_note = self._passed_note or passed
            elif self._seen_now and self._wants_yield():
                self._passed_note = None  # it is back and still needs a yield: it had not passed
            self._ensure_plan(ego, road)
            arrived = self._arrived(now, ego, road)
            if arrived is not None:
                if self._passed_note is not None:
                    arrived += " (the emergency vehicle has already passed)"
                self._go(YieldState.STOPPED_WAITING, now, arrived)
        elif st is YieldState.STOPPED_WAITING:
            passed = self._passed_note or self._passed_reason(now)
            if passed is not None and not self._others_wanting:
                self._go(YieldState.EV_PASSED, now, passed)
        elif st is YieldState.EV_PASSED:
            if self._confirmed(self._yield_run_since, now):
                self._go(YieldState.EV_CONFIRMED, now, f"confirmed an {what} needing a yield")
            elif now - self._entered_s >= cfg.passed_hold_s - _EPS:
                self._go(YieldState.RESUMING, now, f"held {cfg.passed_hold_s:g} s after the EV passed")
        elif st is YieldState.RESUMING:
            target = self._resume_speed(road)
            if self._confirmed(self._yield_run_since, now):
                self._go(YieldState.EV_CONFIRMED, now, f"confirmed an {what} needing a yield while resuming")
            elif ego.vx_mps >= cfg.resumed_speed_fraction * target - _EPS:
                self._go(YieldState.NO_EV, now, f"back to {ego.vx_mps:.1f} m/s")
            elif now - self._entered_s >= cfg.resume_timeout_s - _EPS:
                self._go(YieldState.NO_EV, now, f"resuming took longer than {cfg.resume_timeout_s:g} s")

    def _arrived(self, now: float, ego: VehicleState, road: RoadContext) -> str | None:
        cfg = self.config
        if ego.vx_mps >= cfg.stopped_speed_mps or _containing(road.s_m, road.intersections) is not None:
            self._stopped_since = None
            return None
        if self._stopped_since is None:
            self._stopped_since = now
        left = self._plan.stop_s_m - road.s_m if self._plan is not None else 0.0
        if left <= cfg.arrive_tolerance_m:
            return f"stopped at s={road.s_m:.1f} m, {max(left, 0.0):.1f} m from the stop point"
        if now - self._stopped_since >= cfg.stuck_timeout_s - _EPS:
            return f"stopped {left:.1f} m short of the stop point for {now - self._stopped_since:.1f} s"
        return None

    def _resume_speed(self, road: RoadContext) -> float:
        speed = self.config.resume_speed_mps
        return max(float(road.speed_limit_mps if speed is None else speed), 0.0)

    # --------------------------------------------------------------------------------- the plan

    def _ensure_plan(self, ego: VehicleState, road: RoadContext) -> None:
        """Make the latched plan, or re-make it when the EV changed between crossing and same-road or
        the ego is inside an intersection short of its stop point."""
        b = self._belief
        plan = self._plan
        crossing_now: bool | None = None
        wants = b is not None and self._wants_yield()
        if b is not None and b.relation is not EVRelation.UNKNOWN and wants:
            crossing_now = b.relation is EVRelation.CROSSING
        # a firm stop before an intersection: for an EV heading for it or not yet placed
        firm_ok = b is not None and wants and b.relation in (EVRelation.CROSSING, EVRelation.UNKNOWN)
        inside = _containing(road.s_m, road.intersections)
        if plan is None:
            self._plan = self._make_plan(ego, road, bool(crossing_now), firm_ok)
            self._plan_note = ""
        elif crossing_now is not None and crossing_now != plan.crossing and not plan.unknown_way:
            # (a stop before the intersection for an EV ahead of abeam whose way was unknown stays
            # when the EV is placed: its placement flips between crossing and "on our road" as its
            # distances, compressed beyond the rangers' reach, move it)
            new = self._make_plan(ego, road, crossing_now, firm_ok)
            starts = [float(a) for a, _ in road.intersections]
            crosses = any(plan.stop_s_m < a <= new.stop_s_m for a in starts)
            sooner = new.stop_s_m < plan.stop_s_m - self.config.arrive_tolerance_m
            if plan.before_intersection and (crosses or not sooner):
                # committed to stop before an intersection: never turn that into crossing it, nor
                # change it for a place that flips, unless the car must now stop sooner
                self._plan_note = " (the EV's direction changed: still stopping before the intersection)"
            else:
                self._plan = new
                self._plan_note = " (re-planned: the EV's direction changed)"
        elif inside is not None and plan.stop_s_m < inside[1] + self.config.intersection_exit_margin_m:
            self._plan = self._make_plan(ego, road, plan.crossing)
            self._plan_note = " (re-planned: inside an intersection)"

    def _make_plan(
        self, ego: VehicleState, road: RoadContext, crossing: bool, firm_ok: bool = False
    ) -> _Plan:
        cfg = self.config
        s = float(road.s_m)
        v = max(float(ego.vx_mps), 0.0)
        lead = v * cfg.reaction_time_s
        change = lane_change_length_m(
            v, road.right_edge_offset_m, cfg.max_lat_accel_mps2, cfg.lane_change_min_speed_mps
        )
        brake = v * v / (2.0 * cfg.comfort_decel_mps2)
        boxes = sorted((float(a), float(b)) for a, b in road.intersections)
        target = next(((a, b) for a, b in boxes if b >= s), None) if crossing else None
        unknown_way = False
        if firm_ok and not crossing:
            # not placed: with an intersection within a pull-over (and a lane change) ahead, it may
            # well be heading for it: stop before that intersection as for a crossing EV; so too
            # when it is heard or seen ahead of abeam with the intersection within reach of the
            # decision (it can only meet us through that intersection or on our road ahead)
            near = next(((a, b) for a, b in boxes if a > s), None)
            reach = s + lead + max(brake, change) + change
            b = self._belief
            in_front = b is not None and _finite(b.bearing_rad) and abs(b.bearing_rad) < 0.5 * math.pi
            if near is not None and near[0] - cfg.intersection_margin_m <= reach:
                crossing, target = True, near
            elif in_front and near is not None and near[0] - s <= cfg.max_relevant_distance_m:
                # planned for an EV whose way is unknown, not for a crossing one: a later
                # placement on our road keeps this stop (a re-plan follows only a crossing one)
                crossing, target, unknown_way = True, near, True

        def clear(desired: float) -> float:
            return clear_stop_point(
                s,
                v,
                desired,
                boxes,
                decel_mps2=cfg.comfort_decel_mps2,
                margin_m=cfg.intersection_margin_m,
                min_margin_m=cfg.intersection_min_margin_m,
                exit_margin_m=cfg.intersection_exit_margin_m,
            )

        if target is None:  # pull over; also a crossing EV with no intersection on the map
            desired = s + lead + max(brake, change)
        elif target[0] <= s:  # inside the intersection it heads for: clear it first
            desired = s
        else:
            desired = target[0] - cfg.intersection_margin_m
        stop = clear(desired)
        # an intersection to cross before the stop point: leave room to move over after it
        crossed = [b for a, b in boxes if s < b < stop]
        if crossed and stop < max(crossed) + cfg.intersection_exit_margin_m + change:
            stop = clear(max(crossed) + cfg.intersection_exit_margin_m + change)
        # the comfortable stop is not clear of the intersection ahead, or comfort cannot make it in
        # time (reaction, jerk-limited onset): a firm stop before the intersection, if it can
        ahead = target if crossing else next(((a, b) for a, b in boxes if a > s), None)
        if firm_ok and ahead is not None and ahead[0] > s:
            braking = max(-float(ego.ax_mps2), 0.0)
            comfort_reach = s + firm_stop_distance_m(
                v, cfg.comfort_decel_mps2, cfg.comfort_jerk_mps3, cfg.reaction_time_s, braking
            )
            before = stop < ahead[0]
            if stop > ahead[0] - cfg.firm_min_margin_m or (before and stop < comfort_reach - _EPS):
                reach = s + firm_stop_distance_m(
                    v, cfg.firm_decel_mps2, cfg.firm_jerk_mps3, cfg.reaction_time_s, braking
                )
                firm = max(ahead[0] - cfg.intersection_margin_m, reach)
                if firm <= ahead[0] - cfg.firm_min_margin_m and cfg.firm_decel_mps2 > cfg.comfort_decel_mps2:
                    room = firm - s >= lead + change
                    pull = room and cfg.pull_over_before_intersection
                    return _Plan(True, firm, pull, True, firm=True, unknown_way=unknown_way)
                if before and stop < comfort_reach - _EPS:
                    # neither comfort nor a firm stop makes it before: clear the intersection first
                    stop = clear(ahead[1] + cfg.intersection_exit_margin_m + change)
                    return _Plan(crossing, stop, True, False)
        room = stop - s >= lead + change
        if target is not None and stop < target[0]:
            pull = room and cfg.pull_over_before_intersection
            return _Plan(True, stop, pull, True, unknown_way=unknown_way)
        return _Plan(crossing, stop, True if stop >= desired - _EPS else room, stop < desired - _EPS)

    def _hold_short(self, now: float, b: EVBelief, slow: float, what: str) -> YieldDecision:
        """``prepare`` with a stop point before the intersection ahead: the car brakes as for the stop
        it would make there (``intersection_margin_m`` before it within comfort, else a firm stop
        as the plan's, module docstring "A firm stop") while the call proves itself; when neither
        can stop short of it, plain ``prepare``."""
        cfg = self.config
        s, v, braking = self._road_s, self._ego_v, self._ego_brake
        start = min(float(a) for a, _ in self._boxes if float(a) > s)
        since = self._coming_since.get(b.track_id)
        heard = b.time_s - since if since is not None else 0.0
        stop = start - cfg.intersection_margin_m
        comfort = firm_stop_distance_m(
            v, cfg.comfort_decel_mps2, cfg.comfort_jerk_mps3, cfg.reaction_time_s, braking
        )
        firm: tuple[float, float] | None = None
        if s + comfort > stop + _EPS:
            reach = s + firm_stop_distance_m(
                v, cfg.firm_decel_mps2, cfg.firm_jerk_mps3, cfg.reaction_time_s, braking
            )
            stop = max(stop, reach)
            if stop > start - cfg.firm_min_margin_m or cfg.firm_decel_mps2 <= cfg.comfort_decel_mps2:
                why = f"Heard an {what} for {heard:.1f} s, an intersection too close to stop before: slowing."
                return YieldDecision(now, self._state, "prepare", False, slow, None, why)
            firm = (cfg.firm_decel_mps2, cfg.firm_jerk_mps3)
        how = f", firmly (up to {cfg.firm_decel_mps2:g} m/s²)" if firm else ""
        why = (
            f"Heard an {what} for {heard:.1f} s, its way not known, an intersection ahead: braking to "
            f"stop before it at s={stop:.1f} m{how} unless the call stops within "
            f"{cfg.unplaced_siren_heard_s:g} s."
        )
        if firm is None:
            return YieldDecision(now, self._state, "prepare", False, slow, stop, why)
        return YieldDecision(now, self._state, "prepare", False, slow, stop, why, *firm)

    def _motion(self, ego: VehicleState, road: RoadContext) -> tuple[str, bool, float, float, str]:
        """This period's manoeuvre under the plan: action, pull_over, target speed, stop point, note."""
        cfg = self.config
        plan = self._plan
        assert plan is not None
        s = float(road.s_m)
        v = max(float(ego.vx_mps), 0.0)
        stop = plan.stop_s_m
        left = max(stop - s, 0.0)
        decel = cfg.firm_decel_mps2 if plan.firm else cfg.comfort_decel_mps2
        target = min(
            max(float(road.speed_limit_mps), 0.0),
            math.sqrt(2.0 * decel * left),
            max(v, cfg.creep_speed_mps),
        )
        inside = _containing(s, road.intersections)
        in_way = any(a < stop and b > s for a, b in road.intersections)
        if inside is not None or in_way:
            where = "inside an intersection" if inside is not None else "short of an intersection"
            note = f"{where}: clearing it before stopping at s={stop:.1f} m"
            return "clear_intersection", False, target, stop, note
        if plan.before_intersection:
            pull = plan.pull_over_ok
            action = "stop_before_intersection" if (plan.crossing or not pull) else "pull_over_and_stop"
            edge = "at the right edge " if pull else "in lane "
            how = f", braking firmly (up to {cfg.firm_decel_mps2:g} m/s²)" if plan.firm else ""
            return (
                action,
                pull,
                target,
                stop,
                f"stopping {edge}before the intersection at s={stop:.1f} m{how}",
            )
        return "pull_over_and_stop", True, target, stop, f"pulling over to stop at s={stop:.1f} m"

    # ------------------------------------------------------------------------------- decisions

    def _decide(self, now: float, ego: VehicleState, road: RoadContext) -> YieldDecision:
        st = self._state
        limit = max(float(road.speed_limit_mps), 0.0)
        v = max(float(ego.vx_mps), 0.0)
        what = _describe(self._belief, self._approach)
        if st is YieldState.NO_EV:
            if self._run_since is not None:
                why = f"Possible {what} for {now - self._run_since:.2f} s: confirming, driving on."
            else:
                why = "No active emergency vehicle: driving normally."
            return YieldDecision(now, st, "continue", False, limit, None, why)
        if st is YieldState.RESUMING:
            back = self._resume_speed(road)
            why = f"Emergency vehicle gone: back into the lane and up to {back:.1f} m/s."
            return YieldDecision(now, st, "resume", False, back, None, why)
        if st is YieldState.EV_CONFIRMED and not self._wants_yield():
            b = self._belief
            if b is not None and b.relation is EVRelation.AHEAD:
                why = f"Following the {what} without overtaking it."
                return YieldDecision(now, st, "follow", False, min(v, limit), None, why)
            if self._prepares():
                slow = self.config.duty.prepare_speed_fraction * limit
                if b is not None and self._holding_short(b):
                    return self._hold_short(now, b, slow, what)
                why = f"Heard an {what} but the law asks for more before a yield: slowing, ready to yield."
                return YieldDecision(now, st, "prepare", False, slow, None, why)
            s = float(road.s_m)
            horizon = self.config.max_relevant_distance_m
            if (
                b is not None
                and b.relation is EVRelation.UNKNOWN
                and any(s < a <= s + horizon for a, _ in road.intersections)
            ):
                # its way unknown, an intersection ahead: do not speed towards it, be ready to stop
                slow = self.config.duty.prepare_speed_fraction * limit
                why = f"An {what}, an intersection ahead: slowing, ready to stop before it."
                return YieldDecision(now, st, "prepare", False, slow, None, why)
            return YieldDecision(now, st, "continue", False, limit, None, f"No yield needed for the {what}.")
        if st in (YieldState.STOPPED_WAITING, YieldState.EV_PASSED):
            stop = self._plan.stop_s_m if self._plan is not None else float(road.s_m)
            if st is YieldState.STOPPED_WAITING:
                why = f"Stopped, waiting for the {what} to pass."
            else:
                why = f"Emergency vehicle passed: waiting {self.config.passed_hold_s:g} s before resuming."
            return YieldDecision(now, st, "wait", self._pull_over, 0.0, stop, why)
        # EV_CONFIRMED needing a yield, MOVING_OVER
        self._ensure_plan(ego, road)
        action, pull, target, stop, note = self._motion(ego, road)
        self._pull_over = pull
        if self._passed_note is not None:
            why = f"The emergency vehicle has passed: completing the stop, {note}."
        else:
            why = f"Yielding to the {what}: {note}{self._plan_note}."
        firm = self._plan is not None and self._plan.firm and action == "stop_before_intersection"
        if not firm:
            return YieldDecision(now, st, action, pull, target, stop, why)
        cfg = self.config
        return YieldDecision(
            now, st, action, pull, target, stop, why, cfg.firm_decel_mps2, cfg.firm_jerk_mps3
        )
