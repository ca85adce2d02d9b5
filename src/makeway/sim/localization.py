"""The car's estimate of its own state: a GNSS/IMU localization with noise and bias (issue 30).

The controllers steer on what the car believes its pose to be, not on the truth. A
:class:`Localization` turns the true :class:`~makeway.messages.VehicleState` into that estimate
each control period; :data:`LOCALIZATIONS` names the presets (``makeway simulate --localization``):

* ``perfect`` (default): the truth itself (today's behaviour);
* ``rtk``: an RTK-GNSS receiver fused with an automotive IMU, the class of system a car that steers
  to centimetres needs. Figures, 1σ, per axis:

  - position: white noise 0.02 m and a bias of 0.03 m that wanders as a first-order Gauss–Markov
    process with a 30 s correlation time. RTK-fixed receivers specify about 0.01 m + 1 ppm
    horizontal (e.g. u-blox ZED-F9P) and GNSS/INS systems 0.01–0.02 m RTK position (OxTS RT3000
    class); the bias stands for multipath and the slowly changing RTK solution, which datasheet
    figures leave out;
  - heading: white noise 0.1° (1.7 mrad) and a Gauss–Markov bias of 0.1° (τ 30 s), the order of
    what dual-antenna GNSS/INS systems specify (0.05–0.1°);
  - yaw rate: white noise 0.005 rad/s (0.3 °/s), a conservative figure for an automotive MEMS
    gyro at 100 Hz; its bias is left out (the INS estimates it);
  - speed: white noise 0.03 m/s (wheel odometry fused with GNSS Doppler).

These are this project's choices within those published classes, not one product's datasheet.
A lane-level (not RTK) GNSS of ~0.5 m could not hold a car within the targets' 0.10 m at all; that
case belongs to a camera lane-keeping estimate, not to this model.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from makeway.messages import VehicleState
from makeway.registry import Registry

__all__ = ["LOCALIZATIONS", "Localization", "LocalizationConfig"]


@dataclass(frozen=True)
class LocalizationConfig:
    """Noise (white, per sample) and bias (Gauss–Markov) of the estimate, 1σ, SI units."""

    position_noise_m: float = 0.0
    position_bias_m: float = 0.0
    heading_noise_rad: float = 0.0
    heading_bias_rad: float = 0.0
    bias_time_constant_s: float = 30.0
    yaw_rate_noise_radps: float = 0.0
    speed_noise_mps: float = 0.0

    @property
    def perfect(self) -> bool:
        """No noise and no bias: the estimate is the truth."""
        return not any(
            (
                self.position_noise_m,
                self.position_bias_m,
                self.heading_noise_rad,
                self.heading_bias_rad,
                self.yaw_rate_noise_radps,
                self.speed_noise_mps,
            )
        )


class Localization:
    """Estimates of the true state with :class:`LocalizationConfig`'s noise and bias, seeded.

    The biases start at a random draw from their stationary distribution and evolve as
    ``b_k+1 = φ b_k + σ_b √(1 − φ²) w_k`` with ``φ = exp(−dt/τ)``.
    """

    def __init__(self, config: LocalizationConfig, seed: int = 0) -> None:
        self.config = config
        self._rng = np.random.default_rng(seed)
        c = config
        self._bias = self._rng.standard_normal(3) * np.array(
            [c.position_bias_m, c.position_bias_m, c.heading_bias_rad]
        )

    def estimate(self, truth: VehicleState, dt: float) -> VehicleState:
        """The estimate of ``truth`` one period ``dt`` after the previous one."""
        c = self.config
        if c.perfect:
            return truth
        phi = math.exp(-dt / c.bias_time_constant_s)
        sig = np.array([c.position_bias_m, c.position_bias_m, c.heading_bias_rad]) * math.sqrt(
            1.0 - phi * phi
        )
        w = self._rng.standard_normal(8)
        self._bias = phi * self._bias + sig * w[:3]
        bx, by, bpsi = (float(v) for v in self._bias)
        return replace(
            truth,
            x_m=truth.x_m + bx + c.position_noise_m * float(w[3]),
            y_m=truth.y_m + by + c.position_noise_m * float(w[4]),
            yaw_rad=math.remainder(truth.yaw_rad + bpsi + c.heading_noise_rad * float(w[5]), 2.0 * math.pi),
            yaw_rate_radps=truth.yaw_rate_radps + c.yaw_rate_noise_radps * float(w[6]),
            vx_mps=max(0.0, truth.vx_mps + c.speed_noise_mps * float(w[7])) if truth.vx_mps > 0.0 else 0.0,
        )


def _perfect() -> LocalizationConfig:
    """The truth itself."""
    return LocalizationConfig()


def _rtk() -> LocalizationConfig:
    """RTK-GNSS + IMU (module docstring)."""
    return LocalizationConfig(
        position_noise_m=0.02,
        position_bias_m=0.03,
        heading_noise_rad=math.radians(0.1),
        heading_bias_rad=math.radians(0.1),
        bias_time_constant_s=30.0,
        yaw_rate_noise_radps=0.005,
        speed_noise_mps=0.03,
    )


LOCALIZATIONS: Registry[Callable[[], LocalizationConfig]] = Registry(
    "localization", {"perfect": _perfect, "rtk": _rtk}
)
"""Localization presets by name: ``LOCALIZATIONS[name]()`` gives a :class:`LocalizationConfig`."""
