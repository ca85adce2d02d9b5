"""Physical constants shared by the car-side stages and the simulator.

Both sides import from here, so a microphone-array algorithm and the array simulator that tests it
agree on the speed of sound and the sound-pressure reference without the car depending on the
simulator.
"""

from __future__ import annotations

__all__ = ["P_REF_PA", "SPEED_OF_SOUND"]

SPEED_OF_SOUND = 343.2
"""Speed of sound in air at 20 °C, m/s (331.3·√(1 + 20/273.15))."""

P_REF_PA = 20e-6
"""Reference sound pressure of dB SPL, Pa (0 dB SPL = 20 µPa RMS)."""
