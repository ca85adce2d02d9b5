"""Every command's ``--help`` reads well in a terminal (80 and 120 columns), and unknown names given to
name-taking options end in one line listing the valid names, exit code 2, before any long work.

The commands are found by walking the real click tree of :data:`makeway.cli.main.app`, so a command
added later is checked too.
"""

from __future__ import annotations

import itertools
import re
import time
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from makeway.cli.main import app

runner = CliRunner()
CLIP = "highway_cam_no_ev.mp4"  # small and fast to open


def _command_paths() -> list[tuple[str, ...]]:
    """Every command and sub-command of the app, as argument tuples (the app itself is ``()``)."""
    root = typer.main.get_command(app)
    paths: list[tuple[str, ...]] = []

    def walk(cmd: object, path: tuple[str, ...]) -> None:
        paths.append(path)
        for name, sub in getattr(cmd, "commands", {}).items():  # a group's sub-commands
            walk(sub, (*path, name))

    walk(root, ())
    return paths


COMMANDS = _command_paths()


def _help(path: tuple[str, ...], columns: int) -> str:
    result = runner.invoke(app, [*path, "--help"], env={"COLUMNS": str(columns)}, terminal_width=columns)
    assert result.exit_code == 0, (path, result.output)
    return result.output


def test_the_tree_is_walked() -> None:
    # the walk must reach the nested groups, or the checks below would pass on nothing
    names = {" ".join(p) for p in COMMANDS}
    assert {"detect", "simulate", "classify train", "classify eval", "audio listen", "audio train"} <= names
    assert len(COMMANDS) >= 20


@pytest.mark.parametrize("columns", [80, 120])
@pytest.mark.parametrize("path", COMMANDS, ids=lambda p: " ".join(p) or "makeway")
def test_help_renders_cleanly(path: tuple[str, ...], columns: int) -> None:
    text = _help(path, columns)
    assert "``" not in text, "RST double backticks leak into the help"
    assert "\\[" not in text and "[/" not in text and "[bold" not in text, "rich markup leaks into the help"
    for jargon in ("Framework B", "SPEC §", "Figs.", "seed 00"):
        assert jargon not in text, (jargon, path)
    # nothing wider than the terminal, and the wider terminal is used (no hard 80-column cap)
    assert max(len(line) for line in text.splitlines()) <= columns
    # command lists give each command's first sentence whole, not cut off with "..."
    listing = text.split("Commands:", 1)[1] if "Commands:" in text else ""
    assert "..." not in listing, listing


@pytest.mark.parametrize("path", [p for p in COMMANDS if p], ids=lambda p: " ".join(p))
def test_help_paragraphs_are_not_broken_mid_sentence(path: tuple[str, ...]) -> None:
    """The description's paragraphs are rewrapped to the terminal: within a paragraph, a line ends
    only where the next line's first word would not have fitted (as a docstring's own line breaks
    would otherwise show through at 120 columns)."""
    columns = 120
    text = "\n".join(line.strip() for line in _help(path, columns).splitlines())
    paragraphs = [p.strip("\n") for p in re.split(r"\n{2,}", text) if p.strip()]
    assert paragraphs[0].startswith("Usage:"), paragraphs[0]
    checked = 0
    for para in paragraphs[1:]:
        if para.startswith(("Arguments:", "Options:", "Commands:", "╭")):
            break  # the description ends where the option tables begin
        checked += 1
        lines = para.splitlines()
        for line, following in itertools.pairwise(lines):
            first_word = following.split()[0]
            # 2 columns of indent, 2 of margin: the line could have taken the next word if shorter
            assert len(line) + 1 + len(first_word) > columns - 4, (path, line, following)
    assert checked >= 1, "every command has a description"


def test_detect_help_keeps_the_bracketed_classifier_stage() -> None:
    # rich markup used to eat "[classifier]" (read as a style tag), leaving "SORT →  → smoother"
    text = " ".join(_help(("detect",), 80).split())
    assert "SORT tracker → [crop classifier] → smoother" in text
    assert "→ →" not in text


def test_unknown_classifier_lists_the_shipped_ones_before_reading_the_video(
    video_dir: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    t0 = time.perf_counter()
    r = runner.invoke(app, ["detect", str(video_dir / CLIP), "--classifier", "bogus", "-o", str(out), "-q"])
    elapsed = time.perf_counter() - t0
    assert r.exit_code == 2, (r.exit_code, r.output)
    err = r.stderr
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "bogus" in err
    for name in ("default", "fast", "fastest", "imagenet"):
        assert re.search(rf"\b{name}\b", err), (name, err)
    assert not out.exists(), "nothing written for a bad option"
    assert elapsed < 30, "the name is checked before the video is processed"


@pytest.mark.parametrize(
    ("args", "valid"),
    [
        (["simulate", "--controller", "bogus"], ["ffb", "stanley", "pure_pursuit"]),
        (["simulate", "--perception", "bogus"], ["simulated", "siren"]),
        (["simulate", "bogus"], ["seed003", "curve_behind", "no_ev"]),
        (["audio", "listen", ".", "--baseline", "bogus"], ["gccphat", "srp", "normmusic"]),
    ],
    ids=["controller", "perception", "scenario", "baseline"],
)
def test_unknown_names_list_the_valid_ones(args: list[str], valid: list[str]) -> None:
    r = runner.invoke(app, args)
    assert r.exit_code == 2, (r.exit_code, r.output)
    err = r.stderr
    assert "Traceback" not in err and "error:" in err and "bogus" in err, err
    for name in valid:
        assert name in err, (name, err)


def test_unknown_detector_lists_the_registered_ones(video_dir: Path, tmp_path: Path) -> None:
    r = runner.invoke(
        app, ["detect", str(video_dir / CLIP), "--detector", "bogus", "-o", str(tmp_path / "o"), "-q"]
    )
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert "yolox_nano" in r.stderr and "nanodet_m" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()


def test_unknown_approach_lists_the_methods(tmp_path: Path) -> None:
    from makeway.sense.recording import write_recording
    from makeway.sim.audio_scenarios import simulate_recording

    rec = tmp_path / "rec"
    write_recording(rec, simulate_recording("crossing", 1.0, seed=1, siren="synth", noise="generated"))
    r = runner.invoke(app, ["audio", "listen", str(rec), "--baseline", "gccphat", "--approach", "bogus"])
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert "level" in r.stderr and "trend" in r.stderr, r.stderr
