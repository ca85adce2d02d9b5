"""Every sense of the car in the closed loop, fused into one track per EV (SPEC §7; issue 26 items
1, 2 and 4).

:class:`FusedPerception` is a :class:`~makeway.fuse.source.BeliefSource`. Each simulation step it
collects what the chosen senses published by then and hands it to the multi-EV fusion
(:class:`~makeway.fuse.multi_ev.FusedBeliefSource` over
:class:`~makeway.fuse.multi_ev.MultiEVFusion`), which returns one belief per EV track:

* ``siren`` — the siren stack itself: the roof array's audio rendered as the car drives, the shipped
  networks, the listener (:class:`~makeway.pipeline.siren_perception.SirenPerception`); each
  :class:`~makeway.messages.SirenObservation` is published ``siren_latency_s`` after its window's end.
  The listener decides on the logit mean of :data:`FUSED_LISTEN_SMOOTH` (4) windows, not the 8 of a
  car that only hears (``makeway audio listen``): the windows before a siren starts read logits of
  −14 to −27, so a mean over 8 calls a siren switched on 50 m away 1.05 s after it starts (seed003,
  seed 0; the network is sure from the window ending 0.37 s after it), a mean over 4 at 0.71 s.
  The fused car does not act on that call alone: a siren-only track needs 7 of 9 windows on one
  bearing to be confirmed and is then only prepared for until it is close, placed and approaching
  (:mod:`makeway.decide.duty`); a yield sooner needs the lights seen on the same bearing.
  The simulated array renders every EV's siren (each its own draw), and the listener's further
  sirens (:mod:`~makeway.perceive.audio.multisource`) become further siren measurements;
* ``light`` — the camera rig's lights detector, modelled (:class:`~makeway.sim.cameras.CameraSense`):
  :class:`~makeway.messages.LightObservation` messages per frame, published ``latency_s`` after the
  frame;
* ``v2x`` — alerts at ``rate_hz`` from each V2X-equipped EV (its own broadcast, within
  ``V2XLink.range_m``) and from each of the scenario's roadside units (``Scenario.roadside_units``)
  about every active EV within ``unit_sight_m`` of its pole (position with ``unit_position_sigma_m``
  of noise, as its pixel → road step measures it): encoded and signed as on the air
  (:func:`~makeway.v2x.security.sign_alert`, an identity per EV and per unit under a local root made
  once per process), lost with ``loss_prob``, carried to the car by ``V2XLink.transport``
  (:data:`~makeway.sim.radio.RADIOS`: by default a real zenoh network on loopback, one key per road
  segment, the car subscribed to every segment of its route), read ``latency_s`` after generation,
  checked by the car's
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

import atexit
import functools
import math
import shutil
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from makeway.fuse.multi_ev import FusedBeliefSource, MultiEVFusion, Observation
from makeway.messages import EVBelief, SensorHealth, SirenObservation, V2XObservation, VehicleState
from makeway.perceive.audio.far_range import FarRanger
from makeway.perceive.audio.siren_model import SirenModel
from makeway.pipeline.siren_perception import SirenPerception, SirenPerceptionConfig
from makeway.roadside.geodesy import LocalFrame
from makeway.sim.cameras import CameraFigures, CameraSense
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.radio import RADIOS, Radio
from makeway.sim.scenarios import Scenario
from makeway.sim.world import EVTruth, SimWorld
from makeway.v2x.message import Alert
from makeway.v2x.security import GenerationLocation, Identity, TrustStore, Verifier, keygen, sign_alert

__all__ = ["FUSED_LISTEN_SMOOTH", "SENSE_NAMES", "FusedPerception", "FusedPerceptionConfig", "V2XLink"]

SENSE_NAMES = ("siren", "light", "v2x")
ORIGIN = LocalFrame(48.137, 11.575)  # the simulated world's east-north plane (any place will do)
FUSED_LISTEN_SMOOTH = 4
"""Windows the fused car's siren listener averages for its call (module docstring; a car that only
hears keeps :data:`~makeway.perceive.audio.windows.LISTEN_SMOOTH`)."""


@dataclass(frozen=True)
class V2XLink:
    """The radio link of the simulated alerts: ``rate_hz`` per sender, ``range_m`` of an EV's own
    broadcast, ``loss_prob`` per message, ``latency_s`` from generation to the car's check;
    ``unit_sight_m`` (m) how far a roadside unit's camera sees an EV and ``unit_position_sigma_m``
    (m, per axis) the noise of the position it reports; ``transport`` the carrier of the bytes
    (:data:`~makeway.sim.radio.RADIOS`: ``zenoh`` or ``memory``)."""

    rate_hz: float = 10.0
    range_m: float = 1000.0
    loss_prob: float = 0.1
    latency_s: float = 0.05
    unit_sight_m: float = 60.0
    unit_position_sigma_m: float = 0.5
    transport: str = "zenoh"

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.range_m <= 0 or not 0.0 <= self.loss_prob < 1.0 or self.latency_s < 0:
            raise ValueError("rate_hz, range_m > 0, 0 <= loss_prob < 1 and latency_s >= 0 are needed")
        if self.unit_sight_m <= 0 or self.unit_position_sigma_m < 0:
            raise ValueError("unit_sight_m > 0 and unit_position_sigma_m >= 0 are needed")
        RADIOS[self.transport]  # an unknown name fails here, listing the known ones


@dataclass(frozen=True)
class FusedPerceptionConfig:
    """Settings of :class:`FusedPerception`: which ``senses``, the siren stack's scene (``audio``),
    the cameras' figures, the V2X link, the fusion's settings (``fusion``: keyword arguments of
    :class:`~makeway.fuse.multi_ev.MultiEVFusion`), the siren listener's latency and how many
    windows its call averages (``siren_smooth``, :data:`FUSED_LISTEN_SMOOTH`), ``seed`` for the
    cameras and the link, the siren networks (``model``; default the shipped ones, loaded per
    run) and, opt-in, the far ranger behind them (``far_ranger``, reset at each run's start)."""

    senses: tuple[str, ...] = SENSE_NAMES
    audio: LiveAudioConfig = field(default_factory=LiveAudioConfig)
    cameras: CameraFigures = field(default_factory=CameraFigures)
    v2x: V2XLink = field(default_factory=V2XLink)
    fusion: tuple[tuple[str, float], ...] = ()
    siren_latency_s: float = 0.02
    siren_smooth: int = FUSED_LISTEN_SMOOTH
    seed: int = 0
    model: SirenModel | None = field(default=None, compare=False, repr=False)
    far_ranger: FarRanger | None = field(default=None, compare=False, repr=False)

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
            units=scenario.roadside_units,
        )


@functools.lru_cache(maxsize=1)
def _keys() -> Path:
    """A local root and its trust store in a temporary folder (once per process; the folder, which
    holds private keys, is removed when the process exits)."""
    folder = Path(tempfile.mkdtemp(prefix="makeway-v2x-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    keygen(folder, "rsu")
    return folder


@functools.lru_cache(maxsize=256)
def _identity(name: str) -> Identity:
    """The signing identity ``name`` (``ev<station>`` or ``rsu<k>``; made once per process)."""
    return keygen(_keys(), name)


_DIRECT_SEGMENT = "ev-direct"  # the key EVs' own broadcasts travel on


def _unit_segment(k: int) -> str:
    return f"rsu-{k}"


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
        units: tuple[tuple[float, float], ...] = (),
    ) -> None:
        """``stations``: how many EVs may send alerts (numbered 1, 2, …: ``EVTruth.station_id``);
        ``units``: the roadside units' poles ``(x, y)`` (m, world frame)."""
        self.config = config if config is not None else FusedPerceptionConfig()
        cfg = self.config
        self.world = world if world is not None else SimWorld()
        self.source = FusedBeliefSource(MultiEVFusion(**dict(cfg.fusion)))  # type: ignore[arg-type]
        self.siren: SirenPerception | None = None
        if "siren" in cfg.senses:
            self.siren = SirenPerception(
                duration_s,
                SirenPerceptionConfig(
                    audio=cfg.audio,
                    latency_s=cfg.siren_latency_s,
                    smooth=cfg.siren_smooth,
                    model=cfg.model,
                    far_ranger=cfg.far_ranger,
                ),
                world=self.world,
                initial_speed_mps=initial_speed_mps,
            )
        self.cameras = CameraSense(cfg.cameras, seed=cfg.seed) if "light" in cfg.senses else None
        self._rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 2735]))
        self._siren_done = 0  # siren observations handed over so far
        self._next_frame_s = 0.0
        self._next_alert_s = 0.0
        self._pending: deque[tuple[float, Observation]] = deque()  # (publish time, message)
        self._sequence = 0
        self._verifier: Verifier | None = None
        self._radio: Radio | None = None
        self._epoch = 0.0
        self.units = np.asarray(units, dtype=float).reshape(-1, 2)
        self._unit_rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 1609]))
        if "v2x" in cfg.senses:
            for k in range(1, max(stations, 1) + 1):
                _identity(f"ev{k}")
            for k in range(len(self.units)):
                _identity(f"rsu{k}")
            self._verifier = Verifier(TrustStore.load(_keys() / "trust"))
            self._epoch = float(round(time.time()))
            segments = [_DIRECT_SEGMENT] + [_unit_segment(k) for k in range(len(self.units))]
            self._radio = RADIOS[cfg.v2x.transport](segments)
        self.rejected = 0  # alerts the verifier refused
        self.counts = dict.fromkeys(SENSE_NAMES, 0)  # observations handed to the fusion, per sense

    # ------------------------------------------------------------------------------------ senses

    def _v2x(self, time_s: float) -> None:
        link = self.config.v2x
        ego_evs = self.world.all_evs()
        while self._next_alert_s <= time_s + 1e-9:
            t = self._next_alert_s
            self._next_alert_s += 1.0 / link.rate_hz
            active = [ev for ev in ego_evs if ev.lights or ev.siren]
            for ev in active:
                if ev.v2x:
                    self._send(t, ev, _identity(f"ev{max(ev.station_id, 1)}"), _DIRECT_SEGMENT)
            for k, (ux, uy) in enumerate(self.units):
                for ev in active:
                    if math.hypot(ev.x_m - ux, ev.y_m - uy) <= link.unit_sight_m:
                        noise = self._unit_rng.normal(0.0, link.unit_position_sigma_m, 2)
                        self._send(
                            t,
                            ev,
                            _identity(f"rsu{k}"),
                            _unit_segment(k),
                            (float(noise[0]), float(noise[1])),
                            (ux, uy),
                        )

    def _send(
        self,
        t: float,
        ev: EVTruth,
        ident: Identity,
        segment: str,
        offset_m: tuple[float, float] = (0.0, 0.0),
        unit_m: tuple[float, float] | None = None,
    ) -> None:
        """One alert about ``ev`` generated at ``t`` by ``ident`` on ``segment`` (unless lost);
        ``offset_m``: the sender's error in the reported position (m, world frame); ``unit_m``: where
        a roadside sender stands (world frame; ``None``: the EV sends, from where it is)."""
        link = self.config.v2x
        if self._rng.random() < link.loss_prob:
            return
        lat, lon, _ = ORIGIN.to_geodetic([ev.x_m + offset_m[0], ev.y_m + offset_m[1]])
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
        assert self._radio is not None
        where = None
        if unit_m is not None:
            ulat, ulon, _ = ORIGIN.to_geodetic(list(unit_m))
            where = GenerationLocation.from_degrees(float(ulat), float(ulon))
        self._radio.send(segment, sign_alert(alert, ident, where), t + link.latency_s)

    def _receive(self, now_s: float, data: bytes) -> V2XObservation | None:
        assert self._verifier is not None
        verdict = self._verifier.verify(data, self._epoch + now_s)
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
        ready: list[tuple[float, Observation | bytes]] = [p for p in self._pending if p[0] <= time_s + 1e-9]
        if ready:
            self._pending = deque(p for p in self._pending if p[0] > time_s + 1e-9)
        if self._radio is not None:
            self._v2x(time_s)
            ready.extend(self._radio.deliver(time_s))
        for _, msg in sorted(ready, key=lambda p: p[0]):
            o = self._receive(time_s, msg) if isinstance(msg, bytes) else msg
            if o is None:
                continue
            self.counts[_sense_of(o)] += 1
            self.source.receive(o)
        return self.source.update(time_s, ego)

    def receive_health(self, health: SensorHealth) -> None:
        """A perception stage's health report (e.g. a real camera's ``PerceptionFrame.health``) for
        the next :meth:`update`: it scales that sensor's sense and is named in the beliefs'
        ``sensor_faults`` (the siren listener's travels inside its observations)."""
        self.source.receive(health)

    def beliefs(self) -> list[EVBelief]:
        """One belief per confirmed EV track as of the last :meth:`update`."""
        return self.source.beliefs()

    @property
    def observations(self) -> list[tuple[SirenObservation, EVBelief]]:
        """The siren listener's observations with the siren track's belief (for reports)."""
        return self.siren.observations if self.siren is not None else []

    @property
    def lost(self) -> int:
        """Alerts the carrier failed to move (0 on a healthy loopback network)."""
        return self._radio.lost if self._radio is not None else 0

    def close(self) -> None:
        """Release the V2X carrier's network sessions (idempotent)."""
        if self._radio is not None:
            self._radio.close()


def _sense_of(o: Observation) -> str:
    name = type(o).__name__
    return {"SirenObservation": "siren", "LightObservation": "light", "V2XObservation": "v2x"}[name]
