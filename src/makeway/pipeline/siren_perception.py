"""Siren perception inside the closed loop (SPEC §7): simulated array audio → the siren listener →
the fused EV track → the :class:`~makeway.messages.EVBelief` the yield decision reads.

:class:`SirenPerception` is a :class:`~makeway.fuse.source.BeliefSource`, as the simulated
perception (:class:`~makeway.sim.perception.SimulatedPerception`) is, so
:func:`~makeway.pipeline.closed_loop.run_scenario` takes either. Per simulation step it

1. tells the array simulator (:class:`~makeway.sim.live_array.LiveArraySimulator`) where the ego
   and every EV are and whether each one's siren sounds (each EV has a siren of its own);
2. every ``hop_s`` (0.17 s) renders the audio heard since the last hop and runs the shipped siren
   networks on the latest 0.5 s window (:class:`~makeway.perceive.audio.stream.SirenListener`, the
   ``makeway audio listen`` rule: logit mean of ``smooth`` windows — 8 by default, 4 in the fused
   car (:data:`~makeway.pipeline.fused_perception.FUSED_LISTEN_SMOOTH`) —, stored threshold,
   distance-trend approach classifier);
3. folds the observation into the EV track (:class:`~makeway.fuse.siren_track.SirenTrackFusion`)
   and publishes the belief ``latency_s`` after the window's end (the networks' compute time).

Only the siren is perceived: an EV with lights but no siren is not (the camera is not in this
loop). Every observation is kept in :attr:`SirenPerception.observations` (time, the listener's
message, the belief) for reports.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from makeway.fuse.siren_track import SOURCE, SirenTrackFusion
from makeway.messages import EVBelief, SirenObservation, VehicleState
from makeway.perceive.audio.far_range import FarRanger
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.stream import SirenListener
from makeway.perceive.audio.windows import HOP_S, LISTEN_SMOOTH
from makeway.sim.live_array import LiveArraySimulator, LiveAudioConfig
from makeway.sim.scenarios import Scenario
from makeway.sim.world import SimWorld


@dataclass(frozen=True)
class SirenPerceptionConfig:
    """Settings of :class:`SirenPerception`: the simulated scene (``audio``), the hop, the compute
    latency added to each window's end, how many windows the listener's decision averages
    (``smooth``, default :data:`~makeway.perceive.audio.windows.LISTEN_SMOOTH` as ``makeway audio
    listen``), and the siren networks (``model``; default: the shipped ones, loaded per run — pass
    one to share it between runs) and, opt-in, the far ranger (``far_ranger``)."""

    audio: LiveAudioConfig = field(default_factory=LiveAudioConfig)
    hop_s: float = HOP_S
    latency_s: float = 0.02
    smooth: int = LISTEN_SMOOTH
    model: SirenModel | None = field(default=None, compare=False, repr=False)
    far_ranger: FarRanger | None = field(default=None, compare=False, repr=False)
    """The far ranger (opt-in, :mod:`~makeway.perceive.audio.far_range`; reset at the start of each
    run, so one may be shared between runs); ``None``: none."""

    def __post_init__(self) -> None:
        if self.hop_s <= 0 or self.latency_s < 0 or self.smooth < 1:
            raise ValueError("hop_s must be > 0, latency_s >= 0 and smooth >= 1")

    @property
    def sees_lights(self) -> bool:
        """The siren stack hears only: no camera sees the lights."""
        return False

    def build(self, scenario: Scenario, world: SimWorld) -> SirenPerception:
        """The siren stack for a closed-loop run of ``scenario`` in ``world``."""
        return SirenPerception(
            scenario.duration_s, self, world=world, initial_speed_mps=scenario.ego_speed_mps
        )


class SirenPerception:
    """Array audio → siren listener → EV track → belief, hop by hop (module docstring).

    ``duration_s`` bounds the run; ``world`` shows the EV's truth (where it is, whether its siren
    sounds); ``initial_speed_mps`` is the ego's speed at the start (the wind noise's reference).
    """

    def __init__(
        self,
        duration_s: float,
        config: SirenPerceptionConfig | None = None,
        *,
        world: SimWorld | None = None,
        initial_speed_mps: float = 0.0,
    ) -> None:
        self.config = config if config is not None else SirenPerceptionConfig()
        self.world = world if world is not None else SimWorld()
        cfg = self.config
        model = cfg.model
        self.array = LiveArraySimulator(duration_s, cfg.audio, initial_speed_mps=initial_speed_mps)
        sr = self.array.sample_rate
        self.model = model if model is not None else SirenModel()
        self.listener = SirenListener(
            self.array.mics,
            sr,
            model=self.model,
            smooth=cfg.smooth,
            full_scale_db_spl=self.array.full_scale_db_spl,
            source="the closed loop's simulated array",
            far_ranger=None if cfg.far_ranger is None else cfg.far_ranger.reset(),
        )
        self.fusion = SirenTrackFusion()
        self._win = self.listener.window_samples
        self._hop = round(cfg.hop_s * sr)
        self._buffer = np.zeros((0, len(self.array.mics)), dtype=np.float32)
        self._rendered = 0  # samples rendered so far
        self._next_end = self._win  # sample index where the next window ends
        self._pending: deque[EVBelief] = deque()
        self._last = EVBelief.nothing(0.0, source=SOURCE)
        self.observations: list[tuple[SirenObservation, EVBelief]] = []

    def update(self, time_s: float, ego: VehicleState) -> EVBelief:
        """Advance to ``time_s`` (s) with the ego's state (world frame); return the belief published
        by then."""
        ego_x, ego_y, ego_yaw = ego.x_m, ego.y_m, ego.yaw_rad
        evs = [(e.x_m, e.y_m, e.siren) for e in self.world.all_evs()]
        self.array.observe(time_s, ego_x, ego_y, ego_yaw, None, evs=evs)
        sr = self.array.sample_rate
        while self._next_end / sr <= time_s + 1e-9:
            end = self._next_end
            new = self.array.render(self._rendered / sr, end / sr)
            self._buffer = np.concatenate([self._buffer, new])[-self._win :]
            self._rendered = end
            t_end = end / sr
            obs = self.listener.step(self._buffer.T, t_end)
            belief = self.fusion.update(obs, ego_x, ego_y, ego_yaw)
            self.observations.append((obs, belief))
            self._pending.append(belief)
            self._next_end += self._hop
        while self._pending and self._pending[0].time_s + self.config.latency_s <= time_s + 1e-9:
            self._last = self._pending.popleft()
        return self._last

    def beliefs(self) -> list[EVBelief]:
        """The last published belief when it hears an EV (one EV track)."""
        return [self._last] if self._last.detected else []
