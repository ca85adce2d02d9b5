"""V2X alerts for the command line: make keys, sign an alert, verify files, send alerts over zenoh,
and listen as a car (``makeway v2x …``, ``makeway vehicle listen``)."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from makeway.atomic import atomic_path, write_text_atomic
from makeway.errors import InputError
from makeway.messages import VehicleState
from makeway.v2x.message import SEQUENCE_MODULUS

__all__ = ["DEFAULT_ENDPOINT", "keygen", "listen", "make_alert", "send", "verify_files"]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def keygen(out: Path, name: str = "rsu") -> dict[str, Any]:
    """A unit identity ``out/NAME.key`` (+ ``.cert``) under the local root, and the trust store."""
    from makeway.v2x.security import keygen as make

    ident = make(out, name)
    return {
        "key": str(out / f"{name}.key"),
        "cert": str(out / f"{name}.cert"),
        "trust": str(out / "trust"),
        "signer": ident.signer.hex(),
        "station_id": ident.station_id,
    }


def _next_sequence(key: Path) -> int:
    """The unit's next sequence number, kept in ``KEY.seq`` beside the key (starts at 1)."""
    path = key.with_suffix(".seq")
    last = 0
    if path.exists():
        try:
            last = int(path.read_text(encoding="utf-8").strip())
        except ValueError:
            raise InputError(path, "is not a sequence counter (one integer)") from None
    seq = (last + 1) % SEQUENCE_MODULUS  # DENM sequence numbers are 16 bits
    write_text_atomic(path, f"{seq}\n")
    return seq


def make_alert(
    key: Path,
    out: Path,
    *,
    lat_deg: float,
    lon_deg: float,
    heading_deg: float,
    speed_mps: float,
    siren: bool = True,
    lights: bool = True,
    generation_time_s: float | None = None,
    sequence: int | None = None,
    unit: tuple[float, float, float] | None = None,
    signer: str = "certificate",
) -> dict[str, Any]:
    """Sign one alert with the unit's key and write it to ``out``; return its decoded fields.

    ``signer`` names the signer by its whole certificate (``"certificate"``, the default: any car
    holding the root can check it) or by its HashedId8 (``"digest"``: 155 bytes; the car must
    know the unit already).

    Without ``sequence`` the unit's counter beside the key advances by one; without
    ``generation_time_s`` the alert is stamped now. ``unit`` (latitude, longitude in degrees,
    ellipsoidal height in m) is where the unit stands, 1609.2's generation location; without it the
    EV's position at 0 m.
    """
    from makeway.v2x.message import Alert
    from makeway.v2x.security import GenerationLocation, load_identity, sign_alert

    for name, value in (("--lat", lat_deg), ("--lon", lon_deg), ("--heading-deg", heading_deg)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number")
    if not -90.0 <= lat_deg <= 90.0 or not -180.0 <= lon_deg <= 180.0:
        raise ValueError(f"--lat/--lon {lat_deg}, {lon_deg} are not WGS-84 degrees")
    if not (math.isfinite(speed_mps) and speed_mps >= 0):
        raise ValueError(f"--speed-mps must be >= 0, not {speed_mps}")
    try:
        where = None if unit is None else GenerationLocation.from_degrees(*unit)
    except ValueError as exc:
        raise ValueError(f"--unit-lat/--unit-lon/--unit-height-m: {exc}") from None
    ident = load_identity(key)
    alert = Alert.from_physical(
        station_id=ident.station_id,
        generation_time_s=time.time() if generation_time_s is None else generation_time_s,
        sequence=_next_sequence(key) if sequence is None else sequence,
        lat_deg=lat_deg,
        lon_deg=lon_deg,
        heading_deg=heading_deg,
        speed_mps=speed_mps,
        siren=siren,
        lights=lights,
    )
    with atomic_path(out) as tmp:
        data = sign_alert(alert, ident, where, signer=signer)
        tmp.write_bytes(data)
    return {
        "file": str(out),
        **alert.to_json(),
        **(where or GenerationLocation.of_event(alert)).to_json(),
        "signer": ident.signer.hex(),
        "signer_form": signer,
        "bytes": len(data),
    }


def verify_files(
    files: Sequence[Path],
    trust: Path,
    *,
    replay_cache: Path | None = None,
    max_age_s: float | None = None,
    max_future_s: float | None = None,
    now_s: float | None = None,
) -> list[dict[str, Any]]:
    """Verify each file in order (replays count across the files and the cache); one row per file
    ``{"file", "valid", "reason", ...decoded fields}``. A file that cannot be read raises
    :class:`InputError` before anything is verified or the cache is written."""
    from makeway.v2x.security import (
        DEFAULT_MAX_AGE_S,
        DEFAULT_MAX_FUTURE_S,
        MAX_SIGNED_SIZE,
        ReplayCache,
        TrustStore,
        Verdict,
        Verifier,
    )

    data: list[bytes | Verdict] = []
    for f in files:
        try:
            with Path(f).open("rb") as fh:  # no alert is longer than MAX_SIGNED_SIZE: read no more
                head = fh.read(MAX_SIGNED_SIZE + 1)
                size = os.fstat(fh.fileno()).st_size
        except OSError as exc:
            raise InputError(f, f"cannot be read ({exc.strerror})") from None
        too_big = len(head) > MAX_SIGNED_SIZE
        data.append(
            Verdict(False, f"oversized: {size} bytes, a signed alert has at most {MAX_SIGNED_SIZE}")
            if too_big
            else head
        )
    verifier = Verifier(
        TrustStore.load(trust),
        max_age_s=DEFAULT_MAX_AGE_S if max_age_s is None else max_age_s,
        max_future_s=DEFAULT_MAX_FUTURE_S if max_future_s is None else max_future_s,
        replay=ReplayCache.load(replay_cache) if replay_cache is not None else None,
    )
    now = time.time() if now_s is None else now_s
    rows = [
        {"file": str(f), **(d if isinstance(d, Verdict) else verifier.verify(d, now)).to_json()}
        for f, d in zip(files, data, strict=True)
    ]
    if replay_cache is not None:
        verifier.replay.prune(round((now - verifier.max_age_ms / 1000) * 1000))
        verifier.replay.save(replay_cache)
    return rows


def send(
    files: Sequence[Path],
    segment: str,
    *,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (DEFAULT_ENDPOINT,),
    rate_hz: float = 10.0,
    wait_s: float = 10.0,
) -> dict[str, Any]:
    """Publish signed alert files on a segment at ``rate_hz``, once a subscriber is connected (waits
    up to ``wait_s``). Files are sent as they are: the car decides what is valid."""
    from makeway.v2x.transport import AlertPublisher, open_peer, segment_key

    segment_key(segment)
    payloads = []
    for f in files:
        try:
            payloads.append(Path(f).read_bytes())
        except OSError as exc:
            raise InputError(f, f"cannot be read ({exc.strerror})") from None
    session = open_peer(listen, connect)
    try:
        pub = AlertPublisher(session, segment)
        matched = pub.wait_for_subscribers(wait_s)
        for i, p in enumerate(payloads):
            if i:
                time.sleep(1.0 / rate_hz)
            pub.publish(p)
        time.sleep(0.2)  # let the last samples leave before the session closes
        pub.close()
    finally:
        session.close()
    return {"segment": segment, "key": pub.key, "sent": len(payloads), "subscriber_found": matched}


def listen(
    trust: Path,
    segments: Sequence[str],
    *,
    duration_s: float = math.inf,
    count: int | None = None,
    listen_on: Sequence[str] = (DEFAULT_ENDPOINT,),
    connect: Sequence[str] = (),
    ego: tuple[float, float, float, float] | None = None,
    hold_s: float = 1.0,
    relevance_m: float | None = None,
) -> Iterator[dict[str, Any]]:
    """Subscribe to the segments, verify every payload, and yield one row per payload:
        ``{"key", "valid", "reason", ...decoded fields, "latency_ms", "belief"}``; the belief
        (:class:`~makeway.v2x.belief.V2XBeliefSource`) takes valid alerts only. ``ego`` is
        (lat, lon, heading clockwise from north in degrees, speed m/s): the belief's position is relative
        to it; without it the belief says presence, siren and lights only; ``hold_s`` is how long the belief
    keeps an alert after its generation time. Ends after ``duration_s`` or
        ``count`` payloads, then yields a summary row ``{"summary": {...}}`` (``dropped_unread``: alerts
        that came faster than they were verified and were dropped unread because newer ones of the
        same sender were waiting; see :class:`~makeway.v2x.transport.AlertSubscriber`).
        ``relevance_m`` (with ``ego``): verify on demand — an alert whose EV is farther than this
        (m) from the ego is checked for everything but its signature and reported with
        ``"reason": "not relevant: ..."`` (counted as ``not_relevant``, not as rejected)."""
    from makeway.v2x.belief import LocalFrame, RelevanceArea, V2XBeliefSource
    from makeway.v2x.security import NOT_RELEVANT, TrustStore, Verifier
    from makeway.v2x.transport import AlertSubscriber, open_peer, segment_key

    for s in segments:
        segment_key(s)
    if relevance_m is not None and ego is None:
        raise ValueError("verify on demand (relevance_m) needs the car's position (ego)")
    store = TrustStore.load(trust)
    relevant = (
        RelevanceArea(relevance_m, ego[0], ego[1]) if relevance_m is not None and ego is not None else None
    )
    verifier = Verifier(store, relevant=relevant)
    frame = LocalFrame(ego[0], ego[1]) if ego is not None else None
    source = V2XBeliefSource(frame or LocalFrame(0.0, 0.0), hold_s=hold_s)
    valid = rejected = dropped = not_relevant = 0
    reasons: dict[str, int] = {}
    session = open_peer(listen_on, connect)
    try:
        sub = AlertSubscriber(session, segments, known_signers=set(store.units) - store.revoked)
        for got in sub.receive(duration_s):
            verdict = verifier.verify(got.payload, got.time_s)
            row: dict[str, Any] = {"key": got.key, **verdict.to_json()}
            if verdict.valid and verdict.alert is not None:
                valid += 1
                if verdict.signer is not None and verdict.signer in verifier.learnt:
                    sub.add_known_signer(verdict.signer)  # a unit met through its certificate
                source.receive(verdict.alert)
                row["latency_ms"] = (got.time_s - verdict.alert.generation_time_s) * 1000.0
            elif verdict.reason == NOT_RELEVANT:
                not_relevant += 1
            else:
                rejected += 1
                first = verdict.reason.split(":")[0]
                reasons[first] = reasons.get(first, 0) + 1
            ego_state = None
            if ego is not None:
                yaw = LocalFrame.yaw_from_heading(ego[2])
                ego_state = VehicleState(time_s=got.time_s, x_m=0.0, y_m=0.0, yaw_rad=yaw, vx_mps=ego[3])
            row["belief"] = asdict(source.update(got.time_s, ego_state))
            yield row
            if count is not None and valid + rejected + not_relevant >= count:
                break
        dropped = sub.dropped
        sub.close()
    finally:
        session.close()
    yield {
        "summary": {
            "received": valid + rejected + not_relevant,
            "valid": valid,
            "rejected": rejected,
            "not_relevant": not_relevant,
            "reasons": reasons,
            "dropped_unread": dropped,
        }
    }
