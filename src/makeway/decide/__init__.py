"""Decision stage: when and how to yield to an emergency vehicle (SPEC §6)."""

from makeway.decide.yield_fsm import (
    YieldConfig,
    YieldStateMachine,
    clear_stop_point,
    lane_change_length_m,
    needs_yield,
)

__all__ = ["YieldConfig", "YieldStateMachine", "clear_stop_point", "lane_change_length_m", "needs_yield"]
