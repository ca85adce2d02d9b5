"""Pipelines: the stages wired together and run over inputs.

* :func:`~makeway.pipeline.video.run_video` — Framework B on a video file (detector → SORT → crop
  classifier → smoother → annotated H.264 + JSON lines);
* :func:`~makeway.pipeline.closed_loop.run_scenario` — perceived EV → decision → path → control →
  vehicle in a simulated scenario (perception picked from :data:`~makeway.pipeline.closed_loop.PERCEPTIONS`);
* :func:`~makeway.pipeline.mot.track_mot` — SORT over a MOTChallenge detection file;
* :mod:`~makeway.pipeline.clip_record` — record every track's probability over a clip for replay.

Modules are imported on demand (``from makeway.pipeline.video import run_video``): the closed loop
and the video pipeline pull in different, heavy dependencies.
"""
