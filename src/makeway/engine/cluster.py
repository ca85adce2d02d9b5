"""The data engine's job on Dask (issue 28, items 3 and 5): one task per input, a progress bar
over the whole job, failures listed, the ranked review at the end.

:func:`mine_inputs` is the job. It connects to ``scheduler`` (``tcp://HOST:PORT`` of a running
``dask scheduler``; an unreachable one fails within ``connect_timeout_s`` as one
:class:`~makeway.errors.InputError` line) or, by default, starts a
:class:`distributed.LocalCluster` on the machine: ``workers`` processes (default: the CPU count),
one thread each, on loopback, no dashboard. Every input becomes one task
(:func:`~makeway.engine.mine.run_input`, submitted with ``pure=False``); results are collected as
they complete (``distributed.as_completed``). The output folder ``OUT``:

* ``inputs/<id>/`` — per input: ``samples.csv``, the crops / snippets, ``done.json`` (resumable: a
  rerun with the same settings skips these inputs);
* ``samples.csv`` — every hard sample of the job with its context, ranked (most likely EV first;
  vision and audio ranked on their own);
* ``candidates.csv``, ``contact_sheet.png``, ``labels_template.csv`` — the vision samples in the
  review format of ``makeway classify mine`` (:func:`makeway.train.mining.write_review`; images
  relative to ``OUT/inputs``), more sheets ``contact_sheet_<k>.png`` when there are more than
  ``top`` samples;
* ``audio_candidates.csv`` + ``audio_contact_sheet.png`` — the siren samples (FLAC snippets and
  their spectrograms);
* ``failures.csv`` — ``input,error`` for each input that could not be mined (always written);
* ``engine.json`` — the job's summary: inputs done / skipped / failed, samples, wall time, task
  seconds, workers, scheduler.

Everything at the top level is written atomically after the tasks finish, so an interrupted job
leaves only finished inputs behind; running it again finishes the rest.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from makeway.atomic import atomic_path, check_writable, write_text_atomic
from makeway.engine.inputs import expand_inputs
from makeway.engine.mine import SAMPLE_COLUMNS, MineConfig, read_samples, run_input
from makeway.errors import InputError
from makeway.jsonable import to_jsonable

__all__ = ["EngineRun", "connect", "mine_inputs", "write_engine_review"]

MARKER = "engine.json"
CONNECT_TIMEOUT_S = 5.0


@dataclass
class EngineRun:
    """What :func:`mine_inputs` did (also ``OUT/engine.json``): counts, ``wall_s`` (from connecting to
    the review written), ``task_s`` / ``task_cpu_s`` (the tasks' wall and CPU seconds summed) and
    ``timing``: ``connect_s``, ``submit_s``, ``tasks_s`` (submission to the last result), ``close_s``,
    ``review_s``."""

    out: str
    scheduler: str
    workers: int
    inputs: int
    done: int
    skipped: int
    failed: int
    samples: int
    vision_samples: int
    audio_samples: int
    wall_s: float
    task_s: float
    task_cpu_s: float
    timing: dict[str, float] = field(default_factory=dict)
    failures: list[dict[str, str]] = field(default_factory=list)
    tasks: list[dict[str, Any]] = field(default_factory=list)
    outputs: dict[str, str] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = to_jsonable(asdict(self))
        return out


def connect(
    scheduler: str | None, workers: int | None, *, connect_timeout_s: float = CONNECT_TIMEOUT_S
) -> tuple[Any, Any]:
    """A ``distributed.Client`` and the cluster it started (``None`` for an existing scheduler).

    Raises:
        InputError: ``scheduler`` cannot be reached within ``connect_timeout_s`` (or is not a
            scheduler address).
        ValueError: ``workers < 1``.
    """
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        if "://" not in scheduler:
            raise InputError(scheduler, "not a scheduler address; expected tcp://HOST:PORT")
        try:
            return Client(scheduler, timeout=connect_timeout_s, set_as_default=False), None
        except (OSError, TimeoutError) as exc:
            raise InputError(
                scheduler,
                f"no Dask scheduler answered within {connect_timeout_s:g} s "
                f"({type(exc).__name__}); start one with `dask scheduler` or drop --scheduler",
            ) from None
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ValueError(f"workers must be >= 1, got {n}")
    cluster = LocalCluster(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.ERROR,
    )
    return Client(cluster, set_as_default=False), cluster


def _csv_text(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(list(header))
    writer.writerows(rows)
    return buf.getvalue()


def _ranked(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return sorted(rows, key=lambda r: (-float(r["probability"]), r["input"], r["media"]))


def write_engine_review(out: Path, *, top: int = 64) -> dict[str, Any]:
    """Gather every finished input's samples under ``out/inputs`` and write the ranked review files
    (module docstring); returns the counts and the files written."""
    import cv2
    import numpy as np

    from makeway.train.mining import MiningResult, contact_sheet, write_review

    inputs_dir = out / "inputs"
    vision: list[dict[str, str]] = []
    audio: list[dict[str, str]] = []
    folders = (
        sorted(p for p in inputs_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
        if inputs_dir.is_dir()
        else []
    )
    for folder in folders:
        for row in read_samples(folder):
            row["media"] = f"{folder.name}/{row['media']}"
            (audio if row["kind"] == "recording" else vision).append(row)
    vision, audio = _ranked(vision), _ranked(audio)
    files: dict[str, str] = {}
    rows = [[k + 1, *(r[c] for c in SAMPLE_COLUMNS)] for k, r in enumerate(vision)]
    rows += [[k + 1, *(r[c] for c in SAMPLE_COLUMNS)] for k, r in enumerate(audio)]
    write_text_atomic(out / "samples.csv", _csv_text(["rank", *SAMPLE_COLUMNS], rows))
    files["samples"] = str(out / "samples.csv")
    if vision:
        lowest = min(float(r["probability"]) for r in vision)
        result = MiningResult(
            inputs_dir,
            [inputs_dir / r["media"] for r in vision],
            np.array([float(r["probability"]) for r in vision]),
            [],
            lowest,
        )
        files.update({k: str(v) for k, v in write_review(result, out, top=top).items()})
        for page, first in enumerate(range(top, len(vision), top), start=2):
            part = vision[first : first + top]
            sheet = contact_sheet(
                [inputs_dir / r["media"] for r in part], [float(r["probability"]) for r in part]
            )
            path = out / f"contact_sheet_{page}.png"
            with atomic_path(path) as tmp:
                cv2.imwrite(str(tmp), sheet)
            files[f"contact_sheet_{page}"] = str(path)
    if audio:
        write_text_atomic(
            out / "audio_candidates.csv",
            _csv_text(
                ["rank", "snippet", "probability", "reason", "time_s", "siren"],
                [
                    [k + 1, r["media"], r["probability"], r["reason"], r["time_s"], ""]
                    for k, r in enumerate(audio)
                ],
            ),
        )
        files["audio_candidates"] = str(out / "audio_candidates.csv")
        shown = audio[:top]
        thumbs = [inputs_dir / Path(r["media"]).with_suffix(".jpg") for r in shown]
        sheet = contact_sheet(thumbs, [float(r["probability"]) for r in shown])
        with atomic_path(out / "audio_contact_sheet.png") as tmp:
            cv2.imwrite(str(tmp), sheet)
        files["audio_contact_sheet"] = str(out / "audio_contact_sheet.png")
    return {"vision": len(vision), "audio": len(audio), "files": files}


def mine_inputs(
    names: Sequence[str | Path],
    out: str | Path,
    *,
    config: MineConfig | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    segment_frames: int | None = None,
    top: int = 64,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
    progress: bool = True,
) -> EngineRun:
    """Mine every input of ``names`` for hard samples on a Dask cluster into ``out`` (module
    docstring). ``segment_frames`` cuts whole videos into slices of that many frames, one task each.

    Names that cannot be resolved and inputs whose task fails are listed in ``failures`` (and
    ``OUT/failures.csv``); the others complete.

    Raises:
        InputError: ``out`` cannot be written, or is another program's non-empty folder; the
            scheduler is unreachable (all before any task runs).
        ValueError: no names given.
    """
    from distributed import as_completed

    from makeway.atomic import check_replaceable
    from makeway.progress import progress_bar

    if not names:
        raise ValueError("no inputs given: name videos, image folders, recording folders or logs")

    cfg = config or MineConfig()
    target = check_writable(out, folder=True)
    if target.is_dir() and any(target.iterdir()) and not (target / "inputs").is_dir():
        check_replaceable(target, MARKER)
    inputs, problems = expand_inputs(names, segment_frames=segment_frames)
    failures = [{"input": n, "error": e} for n, e in problems]
    t0 = time.perf_counter()
    client, cluster = connect(scheduler, workers, connect_timeout_s=connect_timeout_s)
    t_connected = time.perf_counter()
    records: list[dict[str, Any]] = []
    try:
        n_workers = (
            len(client.scheduler_info(n_workers=-1).get("workers", {}))
            if scheduler
            else int(workers or os.cpu_count() or 1)
        )
        inputs_dir = target / "inputs"
        inputs_dir.mkdir(parents=True, exist_ok=True)
        # the key names the job (output folder and settings): two jobs on one shared scheduler that
        # mine the same input into different folders must not be merged into one task
        job = hashlib.sha256(f"{target}|{cfg.key()}".encode()).hexdigest()[:8]
        futures = [
            client.submit(run_input, inp, cfg, inputs_dir, pure=False, key=f"mine-{inp.input_id}-{job}")
            for inp in inputs
        ]
        by_key = {f.key: inp.name for f, inp in zip(futures, inputs, strict=True)}
        t_submitted = time.perf_counter()
        with progress_bar("mining", len(futures), enabled=progress, unit="inputs") as advance:
            for fut in as_completed(futures, loop=client.loop):
                try:
                    rec = fut.result()
                except Exception as exc:  # a worker died (a decoder crashed) or run_input's guard missed
                    name = by_key[fut.key]
                    error = f"{name}: the task failed ({type(exc).__name__}: {exc})".splitlines()[0]
                    rec = {"input": name, "status": "failed", "samples": 0, "seconds": 0.0, "error": error}
                records.append(rec)
                advance(1)
        t_results = time.perf_counter()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    by_name = {r["input"]: r for r in records}
    records = [by_name.get(i.name, {"input": i.name, "status": "failed", "error": "lost"}) for i in inputs]
    failures += [
        {"input": r["input"], "error": r.get("error", "")} for r in records if r["status"] == "failed"
    ]
    t_review = time.perf_counter()
    review = write_engine_review(target, top=top)
    write_text_atomic(
        target / "failures.csv", _csv_text(["input", "error"], [[f["input"], f["error"]] for f in failures])
    )
    run = EngineRun(
        out=str(target),
        scheduler=scheduler or "local",
        workers=n_workers,
        inputs=len(inputs) + len(problems),
        done=sum(r["status"] == "done" for r in records),
        skipped=sum(r["status"] == "skipped" for r in records),
        failed=len(failures),
        samples=review["vision"] + review["audio"],
        vision_samples=review["vision"],
        audio_samples=review["audio"],
        wall_s=round(time.perf_counter() - t0, 3),
        task_s=round(sum(float(r.get("seconds", 0.0)) for r in records), 3),
        task_cpu_s=round(sum(float(r.get("cpu_s", 0.0)) for r in records), 3),
        timing={
            "connect_s": round(t_connected - t0, 3),
            "submit_s": round(t_submitted - t_connected, 3),
            "tasks_s": round(t_results - t_submitted, 3),
            "close_s": round(t_review - t_results, 3),
            "review_s": round(time.perf_counter() - t_review, 3),
        },
        failures=failures,
        tasks=records,
        outputs={
            **review["files"],
            "failures": str(target / "failures.csv"),
            "summary": str(target / MARKER),
        },
        config=asdict(cfg),
    )
    write_text_atomic(target / MARKER, json.dumps(run.to_json(), indent=1) + "\n")
    return run
