"""The ``makeway`` command line: thin shells over library functions.

Every command prints a short human summary; ``--json`` (where offered) prints one JSON line last for
machines. Bad input ends with one red ``error:`` line naming the file and the problem, exit code 2,
and no half-written outputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from makeway import __version__
from makeway.cli.common import console, err_console, friendly_errors, new_app, print_json_line

app = new_app(
    "makeway",
    "makeway — notice an active emergency vehicle, localize it, keep the belief stable, and make way.\n\n"
    "Start with `makeway demo` (no data needed), then `makeway detect VIDEO` on a road video.",
)


@app.callback(invoke_without_command=True)
def _main(
    version: Annotated[bool, typer.Option("--version", help="Print the version and exit.")] = False,
) -> None:
    if version:
        console.print(f"makeway {__version__}")
        raise typer.Exit()


# ------------------------------------------------------------------------------------------- detect
@app.command()
@friendly_errors
def detect(
    video: Annotated[
        Path,
        typer.Argument(
            help="Road video (any format OpenCV/FFmpeg reads), or a robotics log: an MCAP file or a "
            "ROS 2 bag folder with a camera topic."
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: makeway_out/<video name>)."),
    ] = None,
    detector: Annotated[str, typer.Option(help="Vehicle detector: yolox_nano or nanodet_m.")] = "yolox_nano",
    model: Annotated[
        Path | None,
        typer.Option(
            help="ONNX weights for the detector "
            "(default: searched in $MAKEWAY_MODELS, ../shared/data/models)."
        ),
    ] = None,
    score_threshold: Annotated[float, typer.Option(help="Detector score threshold.")] = 0.3,
    stride: Annotated[int, typer.Option(min=1, help="Process every N-th frame.")] = 1,
    max_frames: Annotated[int | None, typer.Option(min=1, help="Stop after N processed frames.")] = None,
    no_video: Annotated[bool, typer.Option("--no-video", help="Skip the annotated mp4.")] = False,
    classifier: Annotated[
        str,
        typer.Option(
            help="Per-track EV crop classifier: 'default' (the shipped head on YOLOX-nano + NanoDet-m "
            "features: the accurate one, ~13 ms per crop on 2 cores), 'general' (EfficientNet-Lite0 "
            "fine-tuned on web photos, road photos and road clips: holds up best on photos from other "
            "sources, but flags more ordinary vehicles in road video; ~6 ms per crop), 'fast' (the "
            "shipped 64 px small CNN), 'fastest' (the 32 px small CNN: 100 crops in ~4 ms), "
            "'imagenet' (EfficientNet-Lite0 features: best on still crops, worse on road video), a model "
            "file (.npz head or .onnx CNN) or 'none'. With one, tracks get smoothed EV states (see "
            "docs/model_card_ev_head.md, docs/model_card_ev_general.md, docs/model_card_ev_cnn.md). "
            "Default: 'default'."
        ),
    ] = "default",
    classify_every: Annotated[
        int,
        typer.Option(
            min=1,
            help="Judge each track on every N-th frame only (staggered across tracks; the smoother "
            "skips the others). 1 = every frame; 2 halves the classifier cost.",
        ),
    ] = 1,
    single_view: Annotated[
        bool,
        typer.Option(
            "--single-view",
            help="With the default head: judge each crop by itself, not also by its mirror image "
            "(half the cost; with --classify-every 4 the head keeps >= 2x real time).",
        ),
    ] = False,
    rule: Annotated[
        str,
        typer.Option(
            help="What makes a track an active EV (through the smoother): 'lights+crop' (the default: a "
            "flashing emergency light on or above its box, and the crop classifier says EV), 'lights' "
            "(the flashing light alone, no classifier) or 'crop' (the crop classifier alone, the "
            "earlier rule)."
        ),
    ] = "lights+crop",
    light_detector: Annotated[
        str | None, typer.Option(help="Light detector of the lights rules (default: the project's default).")
    ] = None,
    colours: Annotated[
        str,
        typer.Option(
            help="Emergency-light colours of the lights rules: eu (blue and bluish white; the default), "
            "us (red, blue, white), uk_amber, all, or a comma list."
        ),
    ] = "eu",
    topic: Annotated[
        str | None,
        typer.Option(
            help="Camera topic to read when VIDEO is a log (sensor_msgs Image or CompressedImage, "
            "Foxglove CompressedImage or RawImage). Default: the log's only camera topic."
        ),
    ] = None,
    mcap: Annotated[
        Path | None,
        typer.Option(
            help="Also write the run as an MCAP file that opens in Foxglove: the camera image, "
            "the boxes with their EV state, the tracks."
        ),
    ] = None,
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime",
            help="Play the video as a live camera: frames come at the video's rate and, when the "
            "pipeline falls behind, the oldest waiting frame is dropped, never the newest.",
        ),
    ] = False,
    audio: Annotated[
        bool | None,
        typer.Option(
            "--audio/--no-audio",
            help="Also listen for a siren on the video's sound track and decide each second on "
            "lights and siren together. Default: on when the video has a sound track.",
        ),
    ] = None,
    duty: Annotated[
        str,
        typer.Option(
            help="When to make way, per second: audible_and_visual (default: siren and lights, or "
            "lights for 2 s, mean yield; a siren alone means prepare), germany or uk."
        ),
    ] = "audible_and_visual",
    framework: Annotated[
        str,
        typer.Option(
            help="b (the default): vehicle detector, then the crop classifier judges each track. "
            "a: one detector that tells emergency vehicles from other vehicles by itself (its "
            "per-box EV score feeds the smoother; --model is then that detector's file)."
        ),
    ] = "b",
    as_json: Annotated[bool, typer.Option("--json", help="Print the run summary as one JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Detect, track and judge the vehicles in a road video.

    The pipeline: vehicle detector → SORT tracker → [crop classifier] → smoother, with the light
    detector → light tracker → flash cue beside it: by default a track is an active EV when a
    flashing emergency light is on or above its box and the classifier says EV (--rule). Writes
    OUT/annotated.mp4 (H.264, boxes, ids, EV state colours, light boxes, FPS), OUT/tracks.jsonl
    (one JSON object per frame, with its lights) and OUT/summary.json (timings per stage,
    real-time factor, active EV track ids). VIDEO may be an MCAP file or a ROS 2 bag folder
    (--topic picks the camera); --mcap writes the run for Foxglove.

    With sound (--audio, on by default when the video has a sound track) the siren detector
    listens to the track (mono: whether a siren sounds, not where), and every second of the video
    is decided on lights and siren together: OUT/seconds.jsonl holds, per second, the siren
    probability, whether an emergency vehicle's lights were seen, and the decision (yield,
    prepare or none).
    """
    from makeway.apps.detect import detect as run
    from makeway.perceive.vision.lights import DEFAULT_LIGHT_DETECTOR

    summary = run(
        video,
        out,
        detector=detector,
        model=model,
        score_threshold=score_threshold,
        stride=stride,
        max_frames=max_frames,
        write_video=not no_video,
        classifier=classifier,
        classify_every=classify_every,
        single_view=single_view,
        progress=not quiet,
        rule=rule,
        light_detector=light_detector or DEFAULT_LIGHT_DETECTOR,
        colours=colours,
        topic=topic,
        mcap=mcap,
        realtime=realtime,
        audio=audio,
        duty=duty,
        framework=framework.strip().lower(),
    )
    table = Table(title=f"makeway detect — {video.name}", show_header=False)
    if summary.topic is not None:
        table.add_row("camera topic", summary.topic)
    table.add_row("frames", f"{summary.frames} ({summary.width}×{summary.height} @ {summary.fps:g} fps)")
    table.add_row("real-time factor", f"{summary.realtime_factor:.2f}× ({summary.wall_seconds:.1f} s wall)")
    table.add_row("ms / frame", ", ".join(f"{k} {v:.1f}" for k, v in summary.ms_per_frame.items()))
    table.add_row("tracks", f"{summary.unique_tracks} ids, at most {summary.max_tracks} at once")
    if realtime:
        table.add_row("dropped frames", f"{summary.dropped_frames} (the pipeline fell behind)")
    table.add_row(
        f"active EVs ({summary.rule})",
        ", ".join(f"#{i}" for i in summary.active_ev_tracks) or "none",
    )
    per_second = summary.seconds
    if per_second is not None:
        sound = per_second["audio"]
        table.add_row(
            "sound",
            f"{sound['codec']}, {sound['channels']} ch, {sound['source_rate_hz']} Hz, "
            f"siren heard in {per_second['siren_seconds']} s"
            if sound is not None
            else "not used",
        )
        counts = per_second["decisions"]
        table.add_row(
            f"seconds ({per_second['duty']})",
            f"{per_second['seconds']}: yield {counts['yield']}, prepare {counts['prepare']}, "
            f"none {counts['none']}; lights seen in {per_second['lights_seconds']}",
        )
    for name, path in summary.outputs.items():
        table.add_row(f"→ {name}", path)
    if not as_json:
        console.print(table)
    else:
        print_json_line(summary.to_json())


# ------------------------------------------------------------------------------------------- lights
@app.command()
@friendly_errors
def lights(
    source: Annotated[
        Path,
        typer.Argument(
            help="Road video, a folder of images (no tracking then), or a log (MCAP file, ROS 2 bag folder)."
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: makeway_out/<name>_lights)."),
    ] = None,
    rig: Annotated[
        str | None,
        typer.Option(help="Rig file (YAML) or 'default'; with --camera, each light gets its azimuth."),
    ] = None,
    camera: Annotated[
        str | None,
        typer.Option(
            help="Camera of the rig that recorded SOURCE (the default rig: front, left, right, rear)."
        ),
    ] = None,
    detector: Annotated[
        str | None,
        typer.Option(help="Light detector: verified (default; most accurate), colour (fastest) or cnn."),
    ] = None,
    colours: Annotated[
        str,
        typer.Option(
            help="Emergency-light colours: eu (blue + bluish white), us (red, blue, white), uk_amber, all, "
            "or a comma list such as blue,red."
        ),
    ] = "eu",
    max_frames: Annotated[int | None, typer.Option(min=1, help="Stop after N frames / images.")] = None,
    no_video: Annotated[bool, typer.Option("--no-video", help="Skip the annotated video / images.")] = False,
    topic: Annotated[
        str | None,
        typer.Option(help="Camera topic when SOURCE is a log. Default: the log's only camera topic."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the run summary as one JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Find, track and time lit emergency lights.

    Writes OUT/annotated.mp4 (H.264: light boxes in their colour, track id, flash Hz, azimuth),
    OUT/lights.jsonl (one JSON object per frame: each light's box, colour, score, track id, flash_hz,
    flashing, and azimuth_deg / elevation_deg with --rig/--camera) and OUT/summary.json.
    """
    from makeway.apps.lights import lights as run
    from makeway.perceive.vision.lights import REVIEW_LIGHT_DETECTOR

    summary = run(
        source,
        out,
        rig=rig,
        camera=camera,
        detector=detector or REVIEW_LIGHT_DETECTOR,
        colours=colours,
        max_frames=max_frames,
        write_video=not no_video,
        progress=not quiet,
        topic=topic,
    )
    if as_json:
        print_json_line(summary.to_json())
        return
    table = Table(title=f"makeway lights — {source.name}", show_header=False)
    size = f"{summary.width}×{summary.height}" + (f" @ {summary.fps:g} fps" if summary.fps else "")
    table.add_row("frames", f"{summary.frames} ({size})")
    table.add_row("detector", f"{summary.detector} ({', '.join(summary.colours)})")
    table.add_row("lights", f"{summary.light_detections} detections, {summary.light_tracks} tracks")
    if summary.kind == "video":
        table.add_row("flashing", f"{len(summary.flashing_tracks)} tracks")
        table.add_row(
            "real-time factor", f"{summary.realtime_factor or 0:.2f}× ({summary.ms_per_frame:.1f} ms/frame)"
        )
    for name, path in summary.outputs.items():
        table.add_row(f"→ {name}", path)
    console.print(table)


# -------------------------------------------------------------------------------------------- track
@app.command()
@friendly_errors
def track(
    mot_det: Annotated[Path, typer.Option("--mot-det", help="MOTChallenge detection file (det.txt).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where to write the MOTChallenge tracks.")],
    gt: Annotated[
        Path | None, typer.Option(help="Ground truth (gt.txt): also print MOTA, MOTP, IDF1, ID switches.")
    ] = None,
    max_age: Annotated[int, typer.Option(min=0, help="Frames a track survives unmatched.")] = 1,
    min_hits: Annotated[int, typer.Option(min=0, help="Consecutive hits before a track is reported.")] = 3,
    iou_threshold: Annotated[float, typer.Option(min=0.0, max=1.0, help="Minimum IoU to match.")] = 0.3,
    min_score: Annotated[
        float | None, typer.Option(help="Drop detections scoring below this before tracking.")
    ] = None,
) -> None:
    """Track a MOTChallenge detection file with SORT.

    Writes frame,id,x,y,w,h,1,-1,-1,-1 rows to OUT. With --gt, also prints the CLEAR MOT and
    identity metrics as one JSON line.
    """
    from makeway.apps.mot import track_mot_file

    run = track_mot_file(
        mot_det,
        out,
        gt=gt,
        max_age=max_age,
        min_hits=min_hits,
        iou_threshold=iou_threshold,
        min_score=min_score,
    )
    err_console.print(
        f"tracked {run.frames} frames, {run.detections} detections → {run.tracks} tracks, "
        f"{run.boxes} boxes → {out}",
        highlight=False,
    )
    if run.metrics is not None:
        print_json_line({"sequence": str(mot_det), **run.metrics})


@app.command("mot-eval")
@friendly_errors
def mot_eval(
    gt: Annotated[Path, typer.Argument(help="Ground truth (gt.txt).")],
    tracks: Annotated[Path, typer.Argument(help="Tracker output in MOTChallenge format.")],
    iou: Annotated[float, typer.Option(min=0.0, max=1.0, help="IoU needed for a match.")] = 0.5,
) -> None:
    """Score tracks against ground truth (MOTChallenge files).

    Prints one JSON line: MOTA, MOTP, IDF1, ID switches and their counts.
    """
    from makeway.apps.mot import score_mot_files

    print_json_line(score_mot_files(gt, tracks, iou=iou))


# -------------------------------------------------------------------------------- evaluate-detector
@app.command("evaluate-detector")
@friendly_errors
def evaluate_detector(
    data: Annotated[
        Path, typer.Option("--data", help="YOLO folder (images/ + labels/); class 0 is the EV class.")
    ],
    framework: Annotated[
        str,
        typer.Option(
            help="b: vehicle detector + the crop classifier per box; a: one detector with the "
            "classes EV and other vehicle."
        ),
    ] = "b",
    classifier: Annotated[
        str,
        typer.Option(
            help="Crop classifier: default, general, fast, fastest, imagenet, or a .npz/.onnx file."
        ),
    ] = "default",
    split: Annotated[
        str,
        typer.Option(
            help="all: every image; held_out: the committed held-out part of ambulance_yolo/valid "
            "(src/makeway/data/ambulance_yolo_held_out.txt); validation: the rest of that set."
        ),
    ] = "all",
    score: Annotated[
        str,
        typer.Option(help="Ranking score for AP: product (detector score × P(EV)) or classifier (P(EV))."),
    ] = "product",
    detector: Annotated[str, typer.Option(help="Vehicle detector: yolox_nano or nanodet_m.")] = "yolox_nano",
    model: Annotated[
        Path | None,
        typer.Option(
            help="ONNX weights: of the vehicle detector (b), or of the EV detector (a; default: the "
            "shipped ev_det_yolox.onnx)."
        ),
    ] = None,
    max_images: Annotated[int | None, typer.Option(min=1, help="Score the first N images only.")] = None,
    labels: Annotated[
        str,
        typer.Option(
            "--labels",
            help="Ground truth: corrected (class-0 boxes with the committed ambulance_yolo audit applied: "
            "unlabelled police cars, fire engines and ambulances get a box; "
            "src/makeway/data/ambulance_yolo_corrections.csv) or original (class-0 boxes as they are).",
        ),
    ] = "corrected",
) -> None:
    """Score an EV detector on YOLO images (boxes of class 0).

    With --framework b (the default): vehicle detector → square crop per box → crop classifier; each
    box is an EV detection ranked by its score, and the operating point is the classifier's own
    threshold. With --framework a: one detector trained for two classes (emergency vehicle, other
    vehicle); boxes ranked by their EV score, the operating point stored in the model. A detection
    is correct at IoU >= 0.5. Prints one JSON line: map50, map50_95, precision, recall (at the
    operating point), n_images, n_boxes, framework, classifier, ms_per_image, labels,
    boxes_corrected.
    """
    from makeway.apps.evaluate_detector import evaluate_detector as run

    print_json_line(
        run(
            data,
            framework=framework.strip().lower(),
            classifier=classifier,
            split=split,
            score=score,
            detector=detector,
            model=model,
            max_images=max_images,
            labels=labels,
        )
    )


# --------------------------------------------------------------------------------------------- demo
@app.command()
@friendly_errors
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Report folder.")] = Path("reports/demo"),
    no_video: Annotated[bool, typer.Option("--no-video", help="Skip the annotated mp4.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON line.")] = False,
) -> None:
    """Run the whole system on simulated scenes.

    No data or weights needed. 1) The field-test situation in closed loop (an EV 50 m behind at 13.4
    m/s): yield decision → pull-over path → steering and braking → vehicle, with the Stanley and
    pure-pursuit controllers for comparison; 2) every built-in scenario; 3) the SORT tracker and
    smoother on a simulated roadside camera. Writes OUT/report.md, OUT/summary.json, plots and an
    annotated video.
    """
    from makeway.apps.demo import run_demo

    summary = run_demo(out, write_video=not no_video, progress=not as_json)
    if as_json:
        print_json_line(summary.to_json())
        return
    for part in demo_report(summary, Path(out)):
        console.print(part)


def demo_report(summary: Any, out: Path) -> list[Any]:
    """What ``makeway demo`` prints: tables whose cells wrap (never cut) at any terminal width."""
    m = summary.seed003
    table = Table(title="makeway demo — make way for an emergency vehicle (simulated)")
    table.add_column("EV 50 m behind, ego at 13.4 m/s", overflow="fold")
    table.add_column("makeway", justify="right", overflow="fold")
    table.add_column("field test / target", justify="right", overflow="fold")
    table.add_row("max |e_lat| in the manoeuvre (m)", f"{m['max_abs_e_lat_m']:.3f}", "0.55 / ≤ 0.25")
    table.add_row("settled |e_lat| (m)", f"{m['settled_abs_e_lat_m']:.3f}", "~0.10 / ≤ 0.05")
    yaw = m["yaw_error_range_rad"]
    table.add_row("yaw error range (rad)", f"[{yaw[0]:.3f}, {yaw[1]:.3f}]", "[-0.05, 0.01] / ±0.03")
    for key, label in (
        ("time_active_to_detected_s", "EV on → detected (s)"),
        ("time_active_to_stopped_s", "EV on → stopped (s)"),
        ("min_distance_to_ev_m", "closest approach (m)"),
    ):
        v = m[key]
        table.add_row(label, "—" if v is None else f"{v:.2f}", "")
    table.add_row("action", _words(m["action"]), "pull over and stop")
    h = summary.seed003_siren
    heard = (
        f"Heard by the siren stack (audio → networks → track): detected "
        f"{h['time_active_to_detected_s']:.2f} s after the siren went on, stopped after "
        f"{h['time_active_to_stopped_s']:.2f} s, action {_words(h['action'])}, "
        f"collision {'yes' if h['collision'] else 'no'}."
    )
    sc = Table(title="built-in scenarios")
    for col in ("scenario", "action", "expected", "collision"):
        sc.add_column(col, overflow="fold")
    for name, sm in summary.scenarios.items():
        ok = "[green]" if sm["action_ok"] and not sm["collision"] else "[red]"
        sc.add_row(
            name,
            f"{ok}{_words(sm['action'])}",
            _words(sm["expected_action"]),
            "yes" if sm["collision"] else "no",
        )
    tr = summary.tracking
    tracking = (
        f"Tracking on a simulated roadside camera: MOTA {tr['mota']:.3f}, IDF1 {tr['idf1']:.3f}, "
        f"per-actor precision/recall after smoothing {tr['actor_precision']:.2f}/{tr['actor_recall']:.2f}."
    )
    done = f"report: [bold]{out / 'report.md'}[/]  ({summary.elapsed_s:.1f} s)"
    return [table, heard, sc, tracking, done]


def _words(action: str) -> str:
    """``pull_over_and_stop`` → ``pull over and stop`` (wraps at spaces in a narrow table)."""
    return action.replace("_", " ")


# ----------------------------------------------------------------------------------------- simulate
@app.command()
@friendly_errors
def simulate(
    name: Annotated[
        str,
        typer.Argument(
            help="Scenario: seed003 (the field test: EV behind on a straight road), curve_behind, oncoming, "
            "crossing, signals_off, no_ev, no_ev_urban (crossroads every 70 m), two_evs, occluded_behind, "
            "night_lights_only, siren_only, v2x_corridor."
        ),
    ] = "seed003",
    controller: Annotated[
        str, typer.Option(help="Lateral controller: ffb (feed-forward + feedback), stanley, pure_pursuit.")
    ] = "ffb",
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Write plots (like the field test's) and metrics.json here."),
    ] = None,
    seed: Annotated[
        int, typer.Option(help="Perception seed (noise, dropouts; with --perception siren: the scene).")
    ] = 0,
    path: Annotated[
        Path | None,
        typer.Option(
            help="Recorded path (CSV with x,y columns, metres) to drive the field-test situation on."
        ),
    ] = None,
    perception: Annotated[
        str,
        typer.Option(
            help="simulated: a model of perception (latency, dropouts, noise); siren: the siren stack "
            "itself — the roof array's audio rendered as the car drives, the shipped siren networks, "
            "the fused EV track (about 0.5× real time; hears the siren only, not the lights); vision: "
            "the camera rig's lights detector (modelled: recall by distance, day/night, occlusion, "
            "flashing, false lights); v2x: verified signed alerts of equipped EVs; fused: siren stack, "
            "cameras and V2X fused into one track per EV."
        ),
    ] = "simulated",
    siren: Annotated[
        str,
        typer.Option(
            help="With --perception siren or fused: synth (procedural siren) or real (a held-out real siren; "
            "needs the data)."
        ),
    ] = "synth",
    noise: Annotated[
        str,
        typer.Option(
            help="With --perception siren or fused: generated street noise, or real held-out street "
            "recordings."
        ),
    ] = "generated",
    cameras: Annotated[
        str,
        typer.Option(
            help="With --perception vision or fused: how well the modelled cameras see lit lights — "
            "seed004 (a published field test of a 4-fisheye car: every lit frame to 20–30 m by day, 40–50 m "
            "at night; what a detector meeting the lights targets would do) or makeway (today's lights "
            "detector by day, measured on real frames: a light seen in 35 % of lit frames at 8 m, none "
            "beyond 16 m)."
        ),
    ] = "seed004",
    duty: Annotated[
        str,
        typer.Option(
            help="The duty to yield: audible_and_visual (default: siren and lights, or a verified V2X "
            "alert → yield; siren only → prepare until close; lights only → yield), germany, uk."
        ),
    ] = "audible_and_visual",
    plant: Annotated[
        str,
        typer.Option(
            help="The simulated car: linear (the model the controllers were designed on), or one of "
            "CommonRoad's published vehicle models: kinematic, single_track, single_track_drift "
            "(tyres that saturate), multi_body (body roll and pitch, suspension, four tyres)."
        ),
    ] = "linear",
    vehicle: Annotated[
        str | None,
        typer.Option(
            help="With a CommonRoad plant: ford_escort, bmw320i (default) or vw_vanagon, their published "
            "parameter sets."
        ),
    ] = None,
    road: Annotated[
        str,
        typer.Option(
            help="dry (friction 1.0) or wet (0.5); the tyres saturate on single_track_drift and multi_body."
        ),
    ] = "dry",
    steer_delay: Annotated[
        float,
        typer.Option(
            help="Steering actuator delay in seconds (0 to 0.5, whole 0.01 s steps); the controllers "
            "then predict the car 0.15 s ahead on their own model."
        ),
    ] = 0.0,
    delay_compensation: Annotated[
        bool,
        typer.Option(help="Predict over the steering delay (turn off to see the delay uncompensated)."),
    ] = True,
    localization: Annotated[
        str,
        typer.Option(
            help="What the car knows of its own position: perfect, or rtk (RTK-GNSS with an IMU: a few "
            "cm of noise and slowly wandering bias)."
        ),
    ] = "perfect",
    mcap: Annotated[
        Path | None,
        typer.Option(
            help="Also write the run to an MCAP file that opens in Foxglove: the cars, what the car "
            "believes about the EV, the yield state, the planned and the driven path."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the metrics as one JSON line last.")] = False,
) -> None:
    """Drive a simulated scenario in closed loop.

    The loop: perceived EV → yield decision → path → control → vehicle. Prints max/settled lateral
    error, yaw and yaw-rate error ranges, comfort, the time from the EV switching on to detection and to
    standstill, the closest approach, and the action taken. With --perception siren the EV is heard by
    the siren stack (--out adds siren.png, siren.jsonl). --plant drives a car the controllers were not
    designed on (with --vehicle, --road and --steer-delay); the metrics then add the friction limit.
    """
    from makeway.apps.simulate import simulate as run

    result, scenario, files = run(
        name,
        controller=controller,
        perception=perception,
        seed=seed,
        siren=siren,
        noise=noise,
        cameras=cameras,
        duty=duty,
        path=path,
        out=out,
        plant=plant,
        vehicle=vehicle,
        road=road,
        steer_delay_s=steer_delay,
        delay_compensation=delay_compensation,
        localization=localization,
        mcap=mcap,
    )
    if as_json:
        print_json_line(result.metrics)
        return
    table = Table(title=f"makeway simulate {scenario.name} ({controller})", show_header=False)
    for key, value in result.metrics.items():
        if isinstance(value, float):
            value = f"{value:.3f}"
        elif isinstance(value, list):
            value = "[" + ", ".join(f"{v:.3f}" for v in value) + "]"
        elif isinstance(value, dict):
            value = ", ".join(f"{k} {v}" for k, v in value.items())
        table.add_row(key, str(value))
    for key, file in files.items():
        table.add_row(f"→ {key}", file)
    console.print(table)


# --------------------------------------------------------------------------------------------- info
@app.command()
@friendly_errors
def info() -> None:
    """Show versions, data and model folders, H.264 encoder.

    Lists where the shared data and the detector weights were found and which H.264 encoder writes
    the annotated videos.
    """
    from makeway.apps.info import environment_info

    table = Table(title="makeway info", show_header=False)
    for what, value in environment_info():
        table.add_row(what, value)
    console.print(table)


from makeway.cli.audio import audio_app  # noqa: E402  (sub-apps register after the main commands)
from makeway.cli.classify import classify_app  # noqa: E402
from makeway.cli.engine import engine_app  # noqa: E402
from makeway.cli.light_labels import light_labels_app  # noqa: E402
from makeway.cli.lights_train import lights_train  # noqa: E402
from makeway.cli.logs import logs_app  # noqa: E402
from makeway.cli.rig import rig_app  # noqa: E402
from makeway.cli.roadside import roadside_app  # noqa: E402
from makeway.cli.rsu import rsu_app  # noqa: E402
from makeway.cli.v2x import v2x_app, vehicle_app  # noqa: E402

app.add_typer(classify_app, name="classify")
app.add_typer(audio_app, name="audio")
app.add_typer(engine_app, name="engine")
app.add_typer(rig_app, name="rig")
app.add_typer(logs_app, name="logs")
app.add_typer(roadside_app, name="roadside")
app.add_typer(rsu_app, name="rsu")
app.add_typer(light_labels_app, name="light-labels")
app.command("lights-train")(lights_train)
app.add_typer(v2x_app, name="v2x")
app.add_typer(vehicle_app, name="vehicle")

if __name__ == "__main__":  # pragma: no cover
    app()
