"""The closed loop's live array draws the siren's emitted level from a chosen range (issue 25: real
sirens span about 110–135 dB at 1 m, the networks' training prior 110–120 dB)."""

from __future__ import annotations

import numpy as np
import pytest

from makeway.sim.audio_scenarios import SIREN_LEVEL_DB_1M
from makeway.sim.live_array import LiveArraySimulator, LiveAudioConfig


def test_live_array_siren_level_range() -> None:
    base = LiveArraySimulator(2.0, LiveAudioConfig(seed=4))
    loud = LiveArraySimulator(2.0, LiveAudioConfig(seed=4, siren_level_db=(125.0, 135.0)))
    lo, hi = SIREN_LEVEL_DB_1M
    l0, l1 = base.siren_draws["level_db_1m"], loud.siren_draws["level_db_1m"]
    assert lo <= l0 <= hi and 125.0 <= l1 <= 135.0
    # the same scene otherwise: the same siren signal, louder by exactly the level difference
    ratio = np.sqrt(
        np.mean(np.square(loud._sirens[0].raw, dtype=np.float64))
        / np.mean(np.square(base._sirens[0].raw, dtype=np.float64))
    )
    assert 20 * np.log10(ratio) == pytest.approx(l1 - l0, abs=0.02)
    assert loud.siren_draws["height_m"] == base.siren_draws["height_m"]
    with pytest.raises(ValueError, match="siren_level_db"):
        LiveAudioConfig(siren_level_db=(140.0, 120.0))
