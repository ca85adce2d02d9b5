"""The duty to yield: which evidence of an emergency vehicle obliges the car to give way, as
configuration (issue 26 item 3).

A rule maps what supports one EV's belief to a *duty*:

* ``"yield"`` — pull over and stop (or stop before the intersection; the yield state machine's
  decision table says how);
* ``"prepare"`` — slow to ``prepare_speed_fraction`` of the speed limit, keep the lane, and watch:
  the car yields as soon as the evidence grows to a ``"yield"``;
* ``"ignore"`` — not an EV to act on.

The evidence of a belief (:class:`~makeway.messages.EVBelief`): a verified V2X alert (``"v2x"`` among
its ``sources``), the siren heard (``siren``), lights seen (``lights``). A siren-only belief that is
``siren_close_m`` or nearer and approaching counts as a ``"yield"`` even under a ``"prepare"`` rule: a
siren that close leaves no time to wait for the lights. With ``siren_close_needs_track`` (default)
"close and approaching" must come from the EV's track — placed, with a known relation (behind,
ahead, oncoming, crossing: a position and a speed), not from one listener's distance call: a
siren-like sound in the street noise, heard at a made-up distance, does not move like a vehicle.
Lights alone carry their duty only once the same EV track has shown them for ``lights_only_min_s``
without a break (the yield state machine keeps that time): an EV's light bar flashes for as long
as it drives, while a brake or traffic light that passes the detector's flash check does so for
moments; before that the lights are not acted on. A siren heard on a track whose lights were seen
within ``lights_memory_s`` (default 3 s) counts as "siren and lights" even between two sightings:
a light bar near the cameras' reach is caught in a few flashes a second or less (seed 004: a
quarter of the frames by day at 50 m, and only in its on-phase), so the gaps between sightings of
an EV 50 m behind often exceed the fusion's one-second hold of a sense, while its siren is heard in
every window. The memory counts only beside a siren of the same track: lights alone still need
``lights_only_min_s`` of unbroken sight. A verified alert is acted on up to
``v2x_horizon_m`` away (the yield state machine's ``max_relevant_distance_m`` bounds the others):
an announced EV lets the car open the way long before it can be heard.

**Presets** (:data:`DUTY_PRESETS`, by jurisdiction):

=======================  ===========  ===========  ===========  ===========================================
preset                   siren and    siren only   lights only  basis
                         lights / V2X
=======================  ===========  ===========  ===========  ===========================================
``audible_and_visual``   yield        prepare      yield        the default; the law the seeds cite (Texas
                                                                Transportation Code 545.156: an EV using
                                                                audible *and* visual signals). Lights alone
                                                                (at night an EV often runs without its
                                                                siren) are still a yield: seeing an EV's
                                                                lights and not yielding is never safer
``germany``              yield        prepare      prepare      StVO §38: blue flashing light together
                                                                with the siren orders everyone to clear
                                                                the way at once; the blue light alone
                                                                only warns
``uk``                   yield        yield        yield        Highway Code rule 219: any of flashing
                                                                lights, headlights or sirens asks drivers
                                                                to let the EV through
=======================  ===========  ===========  ===========  ===========================================

A verified V2X alert is a ``"yield"`` in every preset (the signed alert says lights and siren are in
use; the EV is on a call).

**A car that cannot see lights** (no camera among its senses) can never corroborate a siren, so
waiting for the lights would only delay the yield until the EV is on top of it:
:meth:`DutyToYield.for_senses` turns a ``"prepare"`` for a siren alone into a ``"yield"`` for such a
car (the hearing-only perception of the closed loop uses it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from makeway.messages import EVBelief, EVRelation
from makeway.registry import Registry

__all__ = ["DUTIES", "DUTY_PRESETS", "DutyToYield", "duty_of"]

DUTIES = ("yield", "prepare", "ignore")


@dataclass(frozen=True)
class DutyToYield:
    """One jurisdiction's duty to yield (module docstring): the duty for each kind of evidence, the
    distance at which a siren alone becomes a yield, how far a verified alert is acted on, and the
    speed kept while preparing."""

    name: str = "audible_and_visual"
    siren_and_lights: str = "yield"
    v2x_verified: str = "yield"
    siren_only: str = "prepare"
    lights_only: str = "yield"
    siren_close_m: float = 60.0
    siren_close_needs_track: bool = True
    lights_only_min_s: float = 2.0
    lights_memory_s: float = 3.0
    v2x_horizon_m: float = 600.0
    prepare_speed_fraction: float = 0.6

    def __post_init__(self) -> None:
        for f in ("siren_and_lights", "v2x_verified", "siren_only", "lights_only"):
            if getattr(self, f) not in DUTIES:
                raise ValueError(
                    f"DutyToYield.{f} must be one of {', '.join(DUTIES)}, not {getattr(self, f)!r}"
                )
        if not (
            self.siren_close_m >= 0
            and self.v2x_horizon_m >= 0
            and self.lights_only_min_s >= 0
            and self.lights_memory_s >= 0
            and 0 < self.prepare_speed_fraction <= 1
        ):
            raise ValueError(
                "siren_close_m, v2x_horizon_m, lights_only_min_s, lights_memory_s >= 0 and "
                "0 < prepare_speed_fraction <= 1 are needed"
            )

    def for_senses(self, sees_lights: bool) -> DutyToYield:
        """This duty for a car whose senses do (``True``) or do not include cameras that see lights:
        without them a siren alone that would only be prepared for is a yield (module docstring)."""
        if sees_lights or self.siren_only != "prepare":
            return self
        return replace(self, siren_only="yield")


def duty_of(
    belief: EVBelief, duty: DutyToYield, lights_for_s: float = math.inf, lights_ago_s: float = math.inf
) -> str:
    """The duty (``"yield"``, ``"prepare"`` or ``"ignore"``) the evidence behind ``belief`` carries;
    ``lights_for_s`` is how long (s) its track has shown lights without a break (lights alone are
    ignored until it reaches ``lights_only_min_s``); ``lights_ago_s`` how long ago (s) its track last
    showed lights (a siren with lights seen within ``lights_memory_s`` counts as siren and lights)."""
    if not belief.detected:
        return "ignore"
    if "v2x" in belief.sources:
        return duty.v2x_verified
    if belief.siren and (belief.lights or lights_ago_s <= duty.lights_memory_s + 1e-9):
        return duty.siren_and_lights
    if belief.siren:
        d = belief.distance_m
        close = (
            isinstance(d, (int, float))
            and math.isfinite(d)
            and d <= duty.siren_close_m
            and belief.approaching is True
            and (belief.relation is not EVRelation.UNKNOWN or not duty.siren_close_needs_track)
        )
        if duty.siren_only == "prepare" and close:
            return "yield"
        return duty.siren_only
    if belief.lights:
        return duty.lights_only if lights_for_s >= duty.lights_only_min_s - 1e-9 else "ignore"
    return "ignore"


DUTY_PRESETS: Registry[DutyToYield] = Registry(
    "duty preset",
    {
        "audible_and_visual": DutyToYield(),
        "germany": DutyToYield(name="germany", lights_only="prepare"),
        "uk": DutyToYield(name="uk", siren_only="yield", lights_only="yield"),
    },
)
"""Duty-to-yield presets by jurisdiction (module table)."""
