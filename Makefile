# makeway — two commands for a fresh clone: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
RUNTIME := $(VENV)/.runtime
DEV    := $(VENV)/.dev
OUT    ?= reports/demo
# test processes (pytest-xdist); each test file stays on one process, so its module fixtures and
# caches are built once. TEST_WORKERS=0 runs the suite in this process.
TEST_WORKERS ?= 2

.PHONY: venv demo test lint typecheck bench bench-sort bench-video bench-crops bench-detection bench-pull-over \
	bench-siren-loop bench-audio bench-rig bench-v2x bench-fusion bench-roadside bench-lights bench-lights-flash bench-active-rule \
	bench-rsu bench-fusion-ablation bench-mcap bench-engine bench-robust bench-speed bench-crossing bench-crossing-fresh bench-no-ev-2h bench-no-ev-urban-2h bench-range-loop bench-approach-pairing bench-seed003-timeline bench-faults bench-overload bench-overload-listener bench-range bench-bearing-range bench-far-range bench-far-loop bench-far-fused bench-clip-fusion bench-obstacle-links bench-framework-ab bench-cross-source-seeds bench-camera-figures bench-cameras-loop bench-verifier-gate fuzz clean

# `make demo` installs the runtime only; `make test` and the benchmarks add the dev extra (linters,
# scikit-learn, XGBoost, torch for the training tests).
venv: $(DEV)

$(RUNTIME): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e .
	touch $(RUNTIME)

$(DEV): $(RUNTIME)
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(DEV)

demo: $(RUNTIME)
	$(BIN)/makeway demo --out $(OUT)

lint: venv
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

typecheck: venv
	$(BIN)/mypy

test: lint typecheck
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# Benchmarks: the reference SORT (GPL, installed only here, never vendored) is the anchor.
$(VENV)/.bench: $(DEV)
	$(BIN)/python -m pip install -q --no-deps "sort-track==0.0.8" "filterpy==1.4.5"
	touch $(VENV)/.bench

bench-sort: $(VENV)/.bench
	$(BIN)/python benchmarks/bench_sort_mot15.py

bench-video: venv
	$(BIN)/python benchmarks/bench_video_pipeline.py

# the EV crop CNNs' latency and accuracy beside the shipped head; the per-actor smoother sweep
bench-crops: venv
	$(BIN)/python benchmarks/bench_cnn_latency.py
	$(BIN)/python benchmarks/bench_track_sweep.py

# EV crop classifiers across sources: three seeds with and without quality matching, and their
# seed bags (the first run trains 18 EfficientNet-Lite0 fine-tunes, 1–2 h on 2 cores)
bench-cross-source-seeds: venv
	$(BIN)/python benchmarks/bench_cross_source_seeds.py --seeds 0,1,2

# EV detection on images (vehicle detector + crop classifier) on the held-out ambulance_yolo split;
# the detection metrics beside pycocotools / torchmetrics where either is installed
bench-detection: venv
	$(BIN)/python benchmarks/bench_evaluate_detector.py
	$(BIN)/python benchmarks/bench_detection_metrics_reference.py

bench-pull-over: venv
	$(BIN)/python benchmarks/bench_pull_over.py

bench-siren-loop: venv
	$(BIN)/python benchmarks/bench_closed_loop_siren.py

bench-audio: venv
	$(BIN)/python benchmarks/bench_audio_baselines.py
	$(BIN)/python benchmarks/bench_audio_model.py
	$(BIN)/python benchmarks/bench_audio_real.py --sweep 65,75,80,85
	$(BIN)/python benchmarks/bench_audio_real.py --sweep 65,75,80,85 --smooth 8
	$(BIN)/python benchmarks/bench_audio_smoothing.py
	$(BIN)/python benchmarks/bench_audio_multisource.py
	$(BIN)/python benchmarks/bench_audio_approach.py
	$(BIN)/python benchmarks/bench_audio_calibration.py
	$(BIN)/python benchmarks/bench_audio_range_bound.py

# the rig's azimuth beside OpenCV's fisheye model (pure geometry), the unproject speed, and the azimuth of
# rendered lit lamps with the light detector in the loop
bench-rig: venv
	$(BIN)/python benchmarks/bench_rig_azimuth.py
	$(BIN)/python benchmarks/bench_rig_lights_azimuth.py

# signed V2X alerts: attack-suite counts, verification on one core, created → verified latency over zenoh
bench-v2x: venv
	$(BIN)/python benchmarks/bench_v2x.py
	$(BIN)/python benchmarks/bench_v2x_load.py

bench-fusion: venv
	$(BIN)/python benchmarks/bench_fusion_step.py

# audio only / vision only / V2X only / fused on every closed-loop scenario, and no-EV drives
bench-fusion-ablation: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py

bench-roadside: venv
	$(BIN)/python benchmarks/bench_pixel_to_road.py

# lit-light detection on the held-out sources: rule baseline, CNN with and without colour attention
bench-lights: venv
	$(BIN)/python benchmarks/bench_lights.py --breakdown

# how far the lights detectors see by day, carried over to the rig's fisheyes (the simulated cameras' figures)
bench-camera-figures: venv
	$(BIN)/python benchmarks/bench_camera_figures.py

# how the small-lamp verifier's size gate was chosen (grouped CV and validation per gate; ~8 min)
bench-verifier-gate: venv
	$(BIN)/python benchmarks/bench_verifier_gate.py

# the fused car with today's lights detector by day against seed 004's camera figures (seeds 0-3)
bench-cameras-loop: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py --perceptions fused --seeds 4 --no-ev-runs 0 --cameras makeway --scenarios seed003,curve_behind,oncoming,signals_off,no_ev,two_evs,occluded_behind,night_lights_only,siren_only,crossing

# the flash cue as a filter on the light detector's boxes (every frame of the night and validation clips)
bench-lights-flash: venv
	$(BIN)/python benchmarks/bench_lights_flash.py --clips night_ambulance_lights,intersection_cam_ambulance

# the video pipeline's active-EV rules (crop / lights / lights+crop) on the labelled clips; lights speed
bench-active-rule: venv
	$(BIN)/python benchmarks/bench_active_rule.py

# the roadside node on the real clip: signed alerts received and verified by a car process on loopback
bench-rsu: venv
	$(BIN)/python benchmarks/bench_rsu.py

# reading a camera topic from MCAP / ROS 2 bags beside reading the same frames from the mp4
bench-mcap: venv
	$(BIN)/python benchmarks/bench_mcap.py

# the data engine: 1 and 2 Dask workers on one 20-input mining job, scheduler overhead, projection for N
bench-engine: venv
	$(BIN)/python benchmarks/bench_engine_scaling.py

# the pull-over on CommonRoad's vehicle models (3 cars, dry/wet, steering delay) beside Stanley and pure pursuit
bench-robust: venv
	$(BIN)/python benchmarks/bench_robust_pull_over.py

# the crossing with every sense fused: 20 seeds, stop before the intersection (target ≥ 95 %)
bench-crossing: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py --scenarios crossing --perceptions fused --seeds 20 --no-ev-runs 0

# the crossing on 20 fresh seeds (20–39)
bench-crossing-fresh: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py --scenarios crossing --perceptions fused --seeds 20 --first-seed 20 --no-ev-runs 0

# 2 h of no-EV driving with every sense fused (two processes of 180 drives of 20 s)
bench-no-ev-2h: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py --only-no-ev --no-ev-runs 180 --first-no-ev-seed 100 & \
	$(BIN)/python benchmarks/bench_fusion_ablation.py --only-no-ev --no-ev-runs 180 --first-no-ev-seed 280; wait

# the same 2 h on a street with a crossroads every 70 m
bench-no-ev-urban-2h: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py --only-no-ev --no-ev-scenario no_ev_urban --no-ev-runs 180 --first-no-ev-seed 100 & \
	$(BIN)/python benchmarks/bench_fusion_ablation.py --only-no-ev --no-ev-scenario no_ev_urban --no-ev-runs 180 --first-no-ev-seed 280; wait

# the closed loop's speed on the multi-body plant, against the code before the speed work (same run)
bench-speed: venv
	$(BIN)/python benchmarks/bench_closed_loop_speed.py

# sensor faults (dead, clipped, noisy, swapped capsule; dropped, frozen, black frames; clock skew) beside clean
bench-faults: venv
	$(BIN)/python benchmarks/bench_sensor_faults.py

# streaming stages fed 2x and 10x faster than they run, 10 minutes each: latency p50/p99 and memory
bench-overload: venv
	$(BIN)/python benchmarks/bench_overload.py

# the car's V2X listener at 0.5x, 2x and 10x its verification rate, 20 roadside units + 3 EVs, 10 minutes each
bench-overload-listener: venv
	$(BIN)/python benchmarks/bench_overload.py --stages listener --rates 0.5,2,10

# Framework A against B on the labelled road clips (per actor, class flips, ID switches, speed)
bench-framework-ab: venv
	$(BIN)/python benchmarks/bench_framework_ab.py

# lights and siren per second on the real clips with sound (issue 26 item 6)
bench-clip-fusion: venv
	$(BIN)/python benchmarks/bench_clip_fusion.py

bench-obstacle-links: venv
	$(BIN)/python benchmarks/bench_obstacle_links.py

# siren recall and distance per 5 dB band of emitted level; level-independent range cues alone and combined
bench-range: venv
	$(BIN)/python benchmarks/bench_audio_range_levels.py --n 25 --combo wide=localizer+ranger_wide+ranger_wide2
	$(BIN)/python benchmarks/bench_audio_range_cues.py --n 25

# siren range from bearings alone against the car's own motion (bearings-only TMA), measured alone
bench-bearing-range: venv
	$(BIN)/python benchmarks/bench_audio_bearing_range.py --n 30

# sirens beyond 50 m (issue 25): the far ranger against the shipped networks and the level-only
# oracle on held-out far scenes (EVs out to ~300 m, 110–135 dB at 1 m), then the heard closed loop
# without and with it on the same scenes
bench-far-range: venv
	$(BIN)/python benchmarks/bench_audio_far_range.py --n 25

bench-far-loop: venv
	$(BIN)/python benchmarks/bench_closed_loop_siren.py --no-anchor --no-ev-runs 0
	$(BIN)/python benchmarks/bench_closed_loop_siren.py --no-anchor --no-ev-runs 0 --far-ranger

# the fused car (siren, cameras, V2X) without and with the far ranger, same scenes
bench-far-fused: venv
	$(BIN)/python benchmarks/bench_fusion_ablation.py --perceptions fused --seeds 2 --no-ev-runs 0
	$(BIN)/python benchmarks/bench_fusion_ablation.py --perceptions fused --seeds 2 --no-ev-runs 0 --far-ranger

# the heard closed loop with the default and the wide siren rangers, same scenes (loud sirens)
bench-range-loop: venv
	$(BIN)/python benchmarks/bench_closed_loop_siren.py --rangers prior --no-anchor --scenarios crossing,seed003,curve_behind --sirens real --seeds 0,1 --no-ev-runs 0 --siren-level 120,135
	$(BIN)/python benchmarks/bench_closed_loop_siren.py --rangers wide --no-anchor --scenarios crossing,seed003,curve_behind --sirens real --seeds 0,1 --no-ev-runs 0 --siren-level 120,135

# seed003 (EV 50 m behind), fused: where EV on -> stopped goes, stage by stage, beside modelled perception
bench-seed003-timeline: venv
	$(BIN)/python benchmarks/bench_seed003_timeline.py --seeds 8

# the approaching/receding classifiers: each ranger set with each classifier, held out (standard and 110-135 dB sets)
bench-approach-pairing: venv
	$(BIN)/python benchmarks/bench_audio_approach.py --rangers prior,wide
	$(BIN)/python benchmarks/bench_audio_approach.py --rangers prior,wide --n 25 --siren-level 110,135

# the long fuzz run over every reader (about half an hour); the test suite runs a small fixed budget
fuzz: venv
	$(BIN)/python benchmarks/bench_fuzz.py --profile long

bench: bench-sort bench-video bench-crops bench-detection bench-pull-over bench-siren-loop bench-audio bench-rig \
	bench-v2x bench-fusion bench-roadside bench-lights bench-lights-flash bench-active-rule bench-rsu \
	bench-fusion-ablation bench-mcap bench-engine bench-robust bench-speed bench-faults bench-overload bench-overload-listener \
	bench-range bench-clip-fusion bench-framework-ab

clean:
	rm -rf $(VENV) reports .pytest_cache .mypy_cache .ruff_cache
