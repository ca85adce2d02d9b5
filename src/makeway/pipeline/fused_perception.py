"""Every sense of the car in the closed loop, fused into one track per EV (SPEC §7; issue 26 items
1, 2 and 4).

:class:`FusedPerception` is a :class:`~makeway.fuse.source.BeliefSource`. Each simulation step it
collects what the chosen senses published by then and hands it to the multi-EV fusion
(:class:`~makeway.fuse.multi_ev.FusedBeliefSource` over
:class:`~makeway.fuse.multi_ev.MultiEVFusion`), which returns one belief per EV track:

* ``siren`` — the siren stack itself: the roof array's audio rendered as the car drives, the shipped
  networks, the listener (:class:`~makeway.pipeline.siren_perception.SirenPerception`); each
  :class:`~makeway.messages.SirenObservation` is published ``siren_latency_s`` after its window's end.
  The simulated array renders one siren: the scenario's first EV (a second EV is not heard);
* ``light`` — the camera rig's lights detector, modelled (:class:`~makeway.sim.cameras.CameraSense`):
  :class:`~makeway.messages.LightObservation` messages per frame, published ``latency_s`` after the
  frame;
* ``v2x`` — each V2X-equipped EV's alert (directly or relayed by roadside units within
  ``V2XLink.range_m``) at ``rate_hz``: encoded and signed as on the air
  (:func:`~makeway.v2x.security.sign_alert`, a unit identity per EV under a local root made once per
  process), lost with ``loss_prob``, received ``latency_s`` later, checked by the car's
  :class:`~makeway.v2x.security.Verifier` (signature, trust, freshness, replay) and, when valid,
  turned into a verified :class:`~makeway.messages.V2XObservation` in the world frame (the local
  east-north plane of :class:`~makeway.roadside.geodesy.LocalFrame`). The EVs' identities are made
  before the run starts (their certificates are valid from 5 minutes before they were made); the
  alerts' clock is the simulation's time plus the Unix time at which the run started.

Light and siren observations are in the vehicle frame of the moment they were taken; the fusion
reads them with the ego's state when they are published (the latency's ego motion, ≤ 1.5 m at
13.4 m/s, is left as noise). ``senses`` picks any subset: ``("light",)`` is the ``vision``
perception, ``("v2x",)`` the ``v2x`` one, all three ``fused``. Deterministic for a seed.
"""

from __future__ import annotations

import functools
import math
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from makeway.fuse.multi_ev import FusedBeliefSource, MultiEVFusion, Observation
from makeway.messages import EVBelief, SirenObservation, V2XObservation, VehicleState
from makeway.perceive.audio.siren_model import SirenModel
from makeway.pipeline.siren_perception import SirenPerception, SirenPerceptionConfig
from makeway.roadside.geodesy import LocalFrame
from makeway.sim.cameras import CameraFigures, CameraSense
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.scenarios import Scenario
from makeway.sim.world import EVTruth, SimWorld
from makeway.v2x.message import Alert
from makeway.v2x.security import Identity, TrustStore, Verifier, keygen, sign_alert

__all__ = ["SENSE_NAMES", "FusedPerception", "FusedPerceptionConfig", "V2XLink"]

SENSE_NAMES = ("siren", "light", "v2x")
ORIGIN = LocalFrame(48.137, 11.575)  # the simulated world's east-north plane (any place will do)


@dataclass(frozen=True)
class V2XLink:
    """The radio link of the simulated alerts: ``rate_hz`` per EV, ``range_m`` (direct or through
    roadside units), ``loss_prob`` per message, ``latency_s`` from generation to the car's check."""

    rate_hz: float = 10.0
    range_m: float = 1000.0
    loss_prob: float = 0.1
    latency_s: float = 0.05

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.range_m <= 0 or not 0.0 <= self.loss_prob < 1.0 or self.latency_s < 0:
            raise ValueError("rate_hz, range_m > 0, 0 <= loss_prob < 1 and latency_s >= 0 are needed")


@dataclass(frozen=True)
class FusedPerceptionConfig:
    """Settings of :class:`FusedPerception`: which ``senses``, the siren stack's scene (``audio``),
    the cameras' figures, the V2X link, the fusion's settings (``fusion``: keyword arguments of
    :class:`~makeway.fuse.multi_ev.MultiEVFusion`), ``seed`` for the cameras and the link, and the
    siren networks (``model``; default the shipped ones, loaded per run)."""

    senses: tuple[str, ...] = SENSE_NAMES
    audio: LiveAudioConfig = field(default_factory=LiveAudioConfig)
    cameras: CameraFigures = field(default_factory=CameraFigures)
    v2x: V2XLink = field(default_factory=V2XLink)
    fusion: tuple[tuple[str, float], ...] = ()
    siren_latency_s: float = 0.02
    seed: int = 0
    model: SirenModel | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        bad = [s for s in self.senses if s not in SENSE_NAMES]
        if bad or not self.senses:
            raise ValueError(
                f"senses must be a non-empty subset of {', '.join(SENSE_NAMES)}, not {self.senses}"
            )

    @property
    def sees_lights(self) -> bool:
        """Whether the cameras (``"light"``) are among the senses."""
        return "light" in self.senses

    def build(self, scenario: Scenario, world: SimWorld) -> FusedPerception:
        """The fused perception for a closed-loop run of ``scenario`` in ``world``."""
        return FusedPerception(
            scenario.duration_s,
            self,
            world=world,
            initial_speed_mps=scenario.ego_speed_mps,
            stations=len(scenario.evs),
        )


@functools.lru_cache(maxsize=1)
def _keys() -> Path:
    """A local root and its trust store in a temporary folder (once per process)."""
    folder = Path(tempfile.mkdtemp(prefix="makeway-v2x-"))
    keygen(folder, "rsu")
    return folder


@functools.lru_cache(maxsize=16)
def _identity(station: int) -> Identity:
    """The signing identity of the simulated EV number ``station`` (made once per process)."""
    return keygen(_keys(), f"ev{station}")


class FusedPerception:
    """The chosen senses → multi-EV fusion → one belief per EV (module docstring)."""

    def __init__(
        self,
        duration_s: float,
        config: FusedPerceptionConfig | None = None,
        *,
        world: SimWorld | None = None,
        initial_speed_mps: float = 0.0,
        stations: int = 2,
    ) -> None:
        """``stations``: how many EVs may send alerts (numbered 1, 2, …: ``EVTruth.station_id``)."""
        self.config = config if config is not None else FusedPerceptionConfig()
        cfg = self.config
        self.world = world if world is not None else SimWorld()
        self.source = FusedBeliefSource(MultiEVFusion(**dict(cfg.fusion)))  # type: ignore[arg-type]
        self.siren: SirenPerception | None = None
        if "siren" in cfg.senses:
            self.siren = SirenPerception(
                duration_s,
                SirenPerceptionConfig(audio=cfg.audio, latency_s=cfg.siren_latency_s, model=cfg.model),
                world=self.world,
                initial_speed_mps=initial_speed_mps,
            )
        self.cameras = CameraSense(cfg.cameras, seed=cfg.seed) if "light" in cfg.senses else None
        self._rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 2735]))
        self._siren_done = 0  # siren observations handed over so far
        self._next_frame_s = 0.0
        self._next_alert_s = 0.0
        self._pending: deque[tuple[float, Observation | _Signed]] = deque()  # (publish time, message)
        self._sequence = 0
        self._verifier: Verifier | None = None
        self._epoch = 0.0
        if "v2x" in cfg.senses:
            for k in range(1, max(stations, 1) + 1):
                _identity(k)
            self._verifier = Verifier(TrustStore.load(_keys() / "trust"))
            self._epoch = float(round(time.time()))
        self.rejected = 0  # alerts the verifier refused
        self.counts = dict.fromkeys(SENSE_NAMES, 0)  # observations handed to the fusion, per sense

    # ------------------------------------------------------------------------------------ senses

    def _v2x(self, time_s: float) -> None:
        link = self.config.v2x
        ego_evs = self.world.all_evs()
        while self._next_alert_s <= time_s + 1e-9:
            t = self._next_alert_s
            self._next_alert_s += 1.0 / link.rate_hz
            for ev in ego_evs:
                if ev.v2x and (ev.lights or ev.siren):
                    self._send(t, ev)

    def _send(self, t: float, ev: EVTruth) -> None:
        link = self.config.v2x
        ident = _identity(max(ev.station_id, 1))
        if self._rng.random() < link.loss_prob:
            return
        lat, lon, _ = ORIGIN.to_geodetic([ev.x_m, ev.y_m])
        self._sequence = (self._sequence + 1) % 65536
        alert = Alert.from_physical(
            station_id=ident.station_id,
            generation_time_s=self._epoch + t,
            sequence=self._sequence,
            lat_deg=float(lat),
            lon_deg=float(lon),
            heading_deg=90.0 - math.degrees(ev.heading_rad),
            speed_mps=ev.speed_mps,
            siren=ev.siren,
            lights=ev.lights,
        )
        self._pending.append((t + link.latency_s, _Signed(sign_alert(alert, ident), ev)))

    def _receive(self, now_s: float, signed: _Signed) -> V2XObservation | None:
        assert self._verifier is not None
        verdict = self._verifier.verify(signed.data, self._epoch + now_s)
        if not verdict.valid or verdict.alert is None:
            self.rejected += 1
            return None
        a = verdict.alert
        x, y, _ = (float(v) for v in ORIGIN.to_enu(a.lat_deg, a.lon_deg))
        yaw = math.radians(90.0 - a.heading_deg)
        return V2XObservation(
            time_s=a.generation_time_s - self._epoch,
            station_id=a.station_id,
            x_m=x,
            y_m=y,
            heading_rad=math.atan2(math.sin(yaw), math.cos(yaw)),
            speed_mps=a.speed_mps or 0.0,
            verified=True,
            siren=a.siren,
            lights=a.lights,
        )

    # ------------------------------------------------------------------------------------ update

    def update(self, time_s: float, ego: VehicleState) -> EVBelief:
        """Advance to ``time_s`` (s) with the ego's state (world frame); return the most urgent EV's
        belief published by then."""
        cfg = self.config
        if self.siren is not None:
            self.siren.update(time_s, ego)
            obs = self.siren.observations
            while self._siren_done < len(obs):
                heard = obs[self._siren_done][0]
                self._pending.append((heard.t_end + cfg.siren_latency_s, heard))
                self._siren_done += 1
        if self.cameras is not None:
            while self._next_frame_s <= time_s + 1e-9:
                t = self._next_frame_s
                self._next_frame_s += 1.0 / cfg.cameras.rate_hz
                for lo in self.cameras.observe(t, ego, self.world):
                    self._pending.append((t + cfg.cameras.latency_s, lo))
        if self._verifier is not None:
            self._v2x(time_s)
        ready = [p for p in self._pending if p[0] <= time_s + 1e-9]
        if ready:
            self._pending = deque(p for p in self._pending if p[0] > time_s + 1e-9)
        for _, msg in sorted(ready, key=lambda p: p[0]):
            o = self._receive(time_s, msg) if isinstance(msg, _Signed) else msg
            if o is None:
                continue
            self.counts[_sense_of(o)] += 1
            self.source.receive(o)
        return self.source.update(time_s, ego)

    def beliefs(self) -> list[EVBelief]:
        """One belief per confirmed EV track as of the last :meth:`update`."""
        return self.source.beliefs()

    @property
    def observations(self) -> list[tuple[SirenObservation, EVBelief]]:
        """The siren listener's observations with the siren track's belief (for reports)."""
        return self.siren.observations if self.siren is not None else []


@dataclass(frozen=True)
class _Signed:
    """One signed alert on the air (the EV's truth kept for nothing but debugging)."""

    data: bytes
    ev: EVTruth


def _sense_of(o: Observation) -> str:
    name = type(o).__name__
    return {"SirenObservation": "siren", "LightObservation": "light", "V2XObservation": "v2x"}[name]
