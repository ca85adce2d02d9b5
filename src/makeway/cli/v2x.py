"""``makeway v2x …`` (keys, signed alerts, verification, sending) and ``makeway vehicle listen``
(the car's side): signed emergency-vehicle alerts over zenoh on loopback.

Each command parses its options, makes one call into :mod:`makeway.apps.v2x`, and prints. Registered
by the main app as ``v2x`` and ``vehicle``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import EXIT_NEGATIVE, err_console, friendly_errors, new_app, print_json_line

v2x_app = new_app(
    "v2x",
    "Signed emergency-vehicle alerts.\n\n"
    "The alert carries the fields of ETSI's DENM and SAE J2735's EmergencyVehicleAlert, signed with "
    "ECDSA P-256. keygen makes a local root, a unit key and the car's trust store; alert signs one "
    "alert; verify checks alert files as a car would; send publishes them over zenoh on loopback.",
)
vehicle_app = new_app(
    "vehicle",
    "The car's side of V2X alerts.\n\nListen for alerts and turn the valid ones into the EV belief.",
)

_ENDPOINT_HELP = "zenoh endpoint (loopback only), e.g. tcp/127.0.0.1:7447; repeat for several."


@v2x_app.command()
@friendly_errors
def keygen(
    out: Annotated[Path, typer.Option("--out", "-o", help="Key folder (reuses its root if present).")],
    name: Annotated[str, typer.Option(help="Unit name: writes OUT/NAME.key and OUT/NAME.cert.")] = "rsu",
) -> None:
    """Make a signing identity and the trust store that accepts it.

    Writes OUT/root.key and OUT/trust/root.cert (once), OUT/NAME.key, OUT/NAME.cert,
    OUT/trust/units/NAME.cert and OUT/trust/revoked.txt (certificates: IEEE 1609.2, COER).
    Keys are private: never commit them.
    Prints one JSON line (files, signer HashedId8, station id).
    """
    from makeway.apps.v2x import keygen as run

    print_json_line(run(out, name))


@v2x_app.command()
@friendly_errors
def alert(
    key: Annotated[Path, typer.Option("--key", help="Unit key (NAME.key, with NAME.cert beside it).")],
    lat: Annotated[float, typer.Option("--lat", help="EV latitude, WGS-84 degrees.")],
    lon: Annotated[float, typer.Option("--lon", help="EV longitude, WGS-84 degrees.")],
    heading_deg: Annotated[
        float, typer.Option("--heading-deg", help="EV heading, degrees clockwise from north.")
    ],
    speed_mps: Annotated[float, typer.Option("--speed-mps", help="EV speed, m/s.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where to write the signed alert.")],
    siren: Annotated[bool, typer.Option("--siren/--no-siren", help="Siren in use.")] = True,
    lights: Annotated[bool, typer.Option("--lights/--no-lights", help="Light bar in use.")] = True,
    generation_time: Annotated[
        float | None, typer.Option("--generation-time", help="Unix seconds (default: now).")
    ] = None,
    sequence: Annotated[
        int | None,
        typer.Option(min=0, max=65535, help="Sequence number (default: the counter in KEY.seq, +1)."),
    ] = None,
    unit_lat: Annotated[
        float | None, typer.Option(help="Where the unit stands: latitude (default: the EV's position).")
    ] = None,
    unit_lon: Annotated[float | None, typer.Option(help="Where the unit stands: longitude.")] = None,
    unit_height_m: Annotated[
        float, typer.Option(help="The unit's height above the WGS-84 ellipsoid (m).")
    ] = 0.0,
    signer: Annotated[
        str,
        typer.Option(
            help="certificate: carry the unit's certificate (cars need only the root); "
            "digest: its 8-byte id (155 bytes; cars must know the unit)."
        ),
    ] = "certificate",
) -> None:
    """Sign one emergency-vehicle alert and write it.

    About 300 bytes (155 with --signer digest). The alert is an ETSI DENM
    (cause 95, emergency vehicle approaching) signed as IEEE 1609.2 data with
    the unit's ECDSA P-256 key, the signer named by its
    certificate as ETSI TS 103 097 asks of DENMs.

    Prints its decoded fields as one JSON line.
    """
    from makeway.apps.v2x import make_alert

    if (unit_lat is None) != (unit_lon is None):
        raise ValueError("--unit-lat and --unit-lon go together")
    if signer not in ("certificate", "digest"):
        raise ValueError(f"--signer must be certificate or digest, not {signer!r}")
    unit = None if unit_lat is None or unit_lon is None else (unit_lat, unit_lon, unit_height_m)
    print_json_line(
        make_alert(
            key,
            out,
            lat_deg=lat,
            lon_deg=lon,
            heading_deg=heading_deg,
            speed_mps=speed_mps,
            siren=siren,
            lights=lights,
            generation_time_s=generation_time,
            sequence=sequence,
            unit=unit,
            signer=signer,
        )
    )


@v2x_app.command()
@friendly_errors
def verify(
    messages: Annotated[list[Path], typer.Argument(help="Signed alert files, checked in order.")],
    trust: Annotated[Path, typer.Option("--trust", help="Trust store folder (DIR/trust from keygen).")],
    replay_cache: Annotated[
        Path | None,
        typer.Option("--replay-cache", help="JSON file of accepted signer/sequence pairs, read and updated."),
    ] = None,
    max_age_s: Annotated[float, typer.Option(min=0.0, help="Freshness window (s).")] = 10.0,
    max_future_s: Annotated[float, typer.Option(min=0.0, help="Clock-skew allowance (s).")] = 1.0,
) -> None:
    """Check alert files as a car would.

    Checks signer, revocation, signature, generation time and replay.
    One JSON line per file, in order: {"file", "valid", "reason", ...decoded fields}. Exit code 0
    when all are valid, 1 when any is rejected, 2 when a file cannot be read.
    """
    from makeway.apps.v2x import verify_files

    rows = verify_files(
        messages, trust, replay_cache=replay_cache, max_age_s=max_age_s, max_future_s=max_future_s
    )
    for row in rows:
        print_json_line(row)
    if not all(r["valid"] for r in rows):
        raise typer.Exit(code=EXIT_NEGATIVE)


@v2x_app.command()
@friendly_errors
def send(
    messages: Annotated[list[Path], typer.Argument(help="Signed alert files to publish, in order.")],
    segment: Annotated[str, typer.Option("--segment", help="Road segment id (key makeway/v2x/segment/ID).")],
    connect: Annotated[list[str] | None, typer.Option("--connect", help=_ENDPOINT_HELP)] = None,
    listen: Annotated[list[str] | None, typer.Option("--listen", help=_ENDPOINT_HELP)] = None,
    rate_hz: Annotated[float, typer.Option(min=0.1, help="Alerts per second.")] = 10.0,
    wait_s: Annotated[float, typer.Option(min=0.0, help="Wait this long (s) for a subscriber.")] = 10.0,
) -> None:
    """Publish alert files on a road segment.

    Sends over zenoh, by default connecting to a car listening on tcp/127.0.0.1:7447. Prints one JSON
    line: segment, key, count sent, whether a subscriber was found.
    """
    from makeway.apps.v2x import DEFAULT_ENDPOINT
    from makeway.apps.v2x import send as run

    print_json_line(
        run(
            messages,
            segment,
            listen=listen or [],
            connect=connect if connect is not None else [DEFAULT_ENDPOINT],
            rate_hz=rate_hz,
            wait_s=wait_s,
        )
    )


@vehicle_app.command("listen")
@friendly_errors
def listen_cmd(
    trust: Annotated[Path, typer.Option("--trust", help="Trust store folder (DIR/trust from keygen).")],
    segment: Annotated[list[str], typer.Option("--segment", help="Road segment id; repeat for several.")],
    duration: Annotated[
        float | None, typer.Option("--duration", min=0.0, help="Listen this long (s).")
    ] = None,
    count: Annotated[int | None, typer.Option(min=1, help="Stop after this many messages.")] = None,
    listen: Annotated[list[str] | None, typer.Option("--listen", help=_ENDPOINT_HELP)] = None,
    connect: Annotated[list[str] | None, typer.Option("--connect", help=_ENDPOINT_HELP)] = None,
    ego_lat: Annotated[float | None, typer.Option(help="The car's latitude (WGS-84 degrees).")] = None,
    ego_lon: Annotated[float | None, typer.Option(help="The car's longitude (WGS-84 degrees).")] = None,
    ego_heading_deg: Annotated[float, typer.Option(help="The car's heading, degrees from north.")] = 0.0,
    ego_speed_mps: Annotated[float, typer.Option(help="The car's speed (m/s).")] = 0.0,
    hold_s: Annotated[
        float, typer.Option(min=0.0, help="The belief keeps an alert this long (s) after its generation.")
    ] = 1.0,
    relevance_m: Annotated[
        float | None,
        typer.Option(
            min=1.0,
            help="Verify on demand (needs --ego-lat/--ego-lon): check the signature only of alerts whose EV "
            "is within this many metres; the others are reported as not relevant. 1000 is a sensible radius.",
        ),
    ] = None,
) -> None:
    """Listen for alerts as a car.

    Verifies each alert and keeps the EV belief from the valid ones.
    Subscribes over zenoh (default: listens on tcp/127.0.0.1:7447). One JSON line per message:
    {"key", "valid", "reason", ...decoded fields, "belief"}; rejected messages never reach the
    belief. With --ego-lat/--ego-lon the belief has the EV's position in the car's frame. A summary
    line with the counts comes last. Runs until --duration, --count or Ctrl-C.
    """
    from makeway.apps.v2x import DEFAULT_ENDPOINT
    from makeway.apps.v2x import listen as run

    if (ego_lat is None) != (ego_lon is None):
        raise ValueError("--ego-lat and --ego-lon go together")
    if relevance_m is not None and ego_lat is None:
        raise ValueError("--relevance-m needs the car's position: --ego-lat and --ego-lon")
    ego = None if ego_lat is None or ego_lon is None else (ego_lat, ego_lon, ego_heading_deg, ego_speed_mps)
    try:
        for row in run(
            trust,
            segment,
            duration_s=math.inf if duration is None else duration,
            count=count,
            listen_on=listen if listen is not None else [DEFAULT_ENDPOINT],
            connect=connect or [],
            ego=ego,
            hold_s=hold_s,
            relevance_m=relevance_m,
        ):
            print_json_line(row)
    except KeyboardInterrupt:
        err_console.print("stopped")


if __name__ == "__main__":  # pragma: no cover
    v2x_app()
