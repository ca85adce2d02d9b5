"""Decision stage: when and how to yield to an emergency vehicle (SPEC §6), and the duty to yield
as configuration (:mod:`makeway.decide.duty`)."""

from makeway.decide.duty import DUTY_PRESETS, DutyToYield, duty_of
from makeway.decide.yield_fsm import (
    YieldConfig,
    YieldStateMachine,
    clear_stop_point,
    firm_stop_distance_m,
    lane_change_length_m,
    needs_yield,
)

__all__ = [
    "DUTY_PRESETS",
    "DutyToYield",
    "YieldConfig",
    "YieldStateMachine",
    "clear_stop_point",
    "duty_of",
    "firm_stop_distance_m",
    "lane_change_length_m",
    "needs_yield",
]
