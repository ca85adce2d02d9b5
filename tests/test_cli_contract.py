"""The command-line contract (issue 29, item 4; docs/cli_contract.md): exit code 0 done, 1 a negative
result, 2 bad input or usage; one ``error:`` line on stderr naming the file; no output left behind.

Real commands through typer's CliRunner on small inputs: a missing file, a corrupt file, an output
that cannot be written — for a representative set of commands — and fuzzed files through ``track``
and ``v2x verify``. None of the heavy commands runs on real data here."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from typer.main import get_command
from typer.testing import CliRunner

from fuzzing import budget, check_reader, file_contents, mutated_bytes
from makeway.cli.common import EXIT_BAD_INPUT, EXIT_INTERRUPTED, error_line, friendly_errors, new_app
from makeway.cli.main import app
from makeway.errors import InputError

runner = CliRunner()

#: where nothing can be created, even by root (as whom CI runs)
UNWRITABLE = Path("/proc/makeway_out")


def _commands(group: Any, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    out = []
    for name, cmd in sorted(group.commands.items()):
        if hasattr(cmd, "commands"):  # a group (typer may bring its own copy of click)
            out += _commands(cmd, (*prefix, name))
        else:
            out.append(((*prefix, name), cmd))
    return out


def _follows_contract(func: object) -> bool:
    while func is not None:
        if getattr(func, "__makeway_contract__", False):
            return True
        func = getattr(func, "__wrapped__", None)
    return False


def test_every_command_follows_the_contract() -> None:
    """Every command is wrapped by :func:`friendly_errors` (one line, exit code 2 on bad input)."""
    commands = _commands(get_command(app))
    assert len(commands) >= 40  # the walk found the sub-apps
    missing = [" ".join(name) for name, cmd in commands if not _follows_contract(cmd.callback)]
    assert missing == []


def _one_error_line(result: object, *words: str) -> str:
    """Exit code 2 and one ``error:`` line on stderr holding every word; nothing on stdout."""
    r = result
    assert r.exit_code == EXIT_BAD_INPUT, (r.exit_code, r.output, r.exception)  # type: ignore[attr-defined]
    err = r.stderr  # type: ignore[attr-defined]
    assert "Traceback" not in err and err.startswith("error: "), err
    assert len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    assert r.stdout == ""  # type: ignore[attr-defined]
    return err


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("keys")
    r = runner.invoke(app, ["v2x", "keygen", "--out", str(folder)])
    assert r.exit_code == 0, r.output
    return folder


# ------------------------------------------------------------------------- missing and corrupt input
ALERT_ARGS = ["--lat", "59.4", "--lon", "24.7", "--heading-deg", "0", "--speed-mps", "10"]


def _cases(inp: Path, out: Path, keys: Path) -> dict[str, list[str]]:
    """Commands that read ``inp`` (and would write under ``out``)."""
    return {
        "track": ["track", "--mot-det", str(inp), "--out", str(out / "tracks.txt")],
        "mot-eval": ["mot-eval", str(inp), str(inp)],
        "detect": ["detect", str(inp), "--out", str(out / "run"), "-q"],
        "simulate": ["simulate", "--path", str(inp), "--out", str(out / "run")],
        "roadside calibrate-transform": ["roadside", "calibrate-transform", str(inp), "--check"],
        "roadside fit-reference": ["roadside", "fit-reference", str(inp), "--out", str(out / "ref.npz")],
        "roadside locate": ["roadside", "locate", str(inp), "--pixels", str(inp)],
        "rig azimuth": ["rig", "azimuth", str(inp), "front", "640", "360"],
        "light-labels check": ["light-labels", "check", str(inp)],
        "light-labels export": ["light-labels", "export", str(inp), "--out", str(out / "yolo")],
        "audio listen": ["audio", "listen", str(inp), "--baseline", "gccphat"],
        "audio calibrate": ["audio", "calibrate", str(inp)],
        "v2x alert": ["v2x", "alert", "--key", str(inp), *ALERT_ARGS, "--out", str(out / "alert.bin")],
        "v2x verify": ["v2x", "verify", str(keys / "rsu.cert"), "--trust", str(inp)],
        "classify eval": ["classify", "eval", "--data", str(inp), "--model", "fastest"],
    }


CASE_NAMES = list(_cases(Path("in"), Path("out"), Path("keys")))
GARBAGE = b"\x89\x00garbage \xff\xfe,1,2\n[not: {valid\n"


@pytest.mark.parametrize("case", CASE_NAMES)
@pytest.mark.parametrize("kind", ["missing", "corrupt"])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(
    tmp_path: Path, keys: Path, case: str, kind: str
) -> None:
    inp = tmp_path / ("missing.txt" if kind == "missing" else "corrupt.txt")
    if kind == "corrupt":
        inp.write_bytes(GARBAGE)
    if case in ("v2x verify", "classify eval") and kind == "corrupt":
        inp = tmp_path / "corrupt_dir"  # these read a folder: one holding a corrupt file
        inp.mkdir()
        (inp / ("root.cert" if case == "v2x verify" else "labels.csv")).write_bytes(GARBAGE)
    out = tmp_path / "out"
    r = runner.invoke(app, _cases(inp, out, keys)[case])
    _one_error_line(r, str(inp))
    assert not out.exists()  # no output, not even its folder


# --------------------------------------------------------------------------------- unwritable outputs
@pytest.mark.parametrize(
    "args",
    [
        ["v2x", "keygen", "--out", "{out}"],
        ["v2x", "alert", "--key", "{key}", *ALERT_ARGS, "--out", "{out}/alert.bin"],
        ["track", "--mot-det", "{det}", "--out", "{out}/tracks.txt"],
        ["audio", "simulate", "--out", "{out}", "--n", "1", "-q"],
        ["demo", "--out", "{out}"],
    ],
    ids=lambda a: " ".join(w for w in a[:2] if not w.startswith("-")),
)
def test_unwritable_output_is_one_line_exit_2(tmp_path: Path, keys: Path, args: list[str]) -> None:
    det = tmp_path / "det.txt"
    det.write_text("1,-1,10,10,20,40,0.9\n2,-1,11,10,20,40,0.9\n")
    filled = [a.format(out=UNWRITABLE, key=keys / "rsu.key", det=det) for a in args]
    r = runner.invoke(app, filled)
    _one_error_line(r, str(UNWRITABLE))


def test_output_over_a_file_is_refused_and_the_file_kept(tmp_path: Path) -> None:
    det = tmp_path / "det.txt"
    det.write_text("1,-1,10,10,20,40,0.9\n")
    blocker = tmp_path / "blocker"
    blocker.write_text("keep me\n")
    r = runner.invoke(app, ["track", "--mot-det", str(det), "--out", str(blocker / "tracks.txt")])
    _one_error_line(r, str(blocker))
    assert blocker.read_text() == "keep me\n"


# --------------------------------------------------------------------------- exit codes 0, 1 and 2
def test_v2x_verify_exit_codes(tmp_path: Path, keys: Path) -> None:
    """0: every alert valid; 1: one rejected (a negative result, not an error); 2: unreadable."""
    alert = tmp_path / "a.bin"
    args = ["v2x", "alert", "--key", str(keys / "rsu.key"), "--lat", "59.437", "--lon", "24.754"]
    r = runner.invoke(app, [*args, "--heading-deg", "90", "--speed-mps", "12", "--out", str(alert)])
    assert r.exit_code == 0, r.output
    trust = str(keys / "trust")
    r = runner.invoke(app, ["v2x", "verify", str(alert), "--trust", trust])
    assert r.exit_code == 0 and json.loads(r.stdout)["valid"] is True
    tampered = tmp_path / "t.bin"
    data = bytearray(alert.read_bytes())
    data[20] ^= 1
    tampered.write_bytes(bytes(data))
    r = runner.invoke(app, ["v2x", "verify", str(alert), str(tampered), "--trust", trust])
    assert r.exit_code == 1, r.output
    rows = [json.loads(line) for line in r.stdout.splitlines()]
    assert [row["valid"] for row in rows] == [True, False] and r.stderr == ""
    r = runner.invoke(app, ["v2x", "verify", str(alert), str(tmp_path / "gone.bin"), "--trust", trust])
    _one_error_line(r, "gone.bin")


def test_usage_errors_exit_2() -> None:
    r = runner.invoke(app, ["track", "--max-age", "-3"])
    assert r.exit_code == 2 and "Traceback" not in r.output
    r = runner.invoke(app, ["no-such-command"])
    assert r.exit_code == 2


def test_os_errors_and_interrupts_follow_the_contract(tmp_path: Path) -> None:
    """An operating-system error on a file (a full disk, no permission) is one line naming the file,
    exit 2; Ctrl-C exits 130 with one line."""
    demo = new_app("demo", "A test app.")
    target = tmp_path / "out" / "x.bin"

    @demo.command()
    @friendly_errors
    def write(what: str) -> None:
        if what == "disk":
            raise OSError(28, "No space left on device", str(target))
        if what == "stop":
            raise KeyboardInterrupt
        raise InputError(target, "has [brackets] that are not markup")

    r = runner.invoke(demo, ["disk"])
    assert _one_error_line(r, str(target), "No space left on device")
    r = runner.invoke(demo, ["stop"])
    assert r.exit_code == EXIT_INTERRUPTED and len(r.stderr.strip().splitlines()) == 1
    r = runner.invoke(demo, ["other"])
    _one_error_line(r, "has [brackets] that are not markup")
    assert error_line(PermissionError(13, "Permission denied", "/a/b")) == "/a/b: Permission denied"
    assert error_line(ValueError("two\nlines")) == "two lines"


# ------------------------------------------------------------------------------ fuzzed, end to end
def test_fuzz_track_through_the_cli(mot15_root: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    """Fuzzed detection files through ``makeway track``: exit 0 with the output, or exit 2, one
    line naming the file, and no output."""
    seed = "\n".join((mot15_root / "TUD-Campus" / "det" / "det.txt").read_text().splitlines()[:25]) + "\n"
    work = tmp_path_factory.mktemp("cli_track")

    @budget(0.5)
    @given(data=file_contents(seed))
    # found by the long run: a box at y = 1.15e18 has height 0 in floats, and SORT divided by it
    @example(data=b"1,-1,281.9,1.152921504606847e+18,187.4,79.9,0.99\n2,-1,281.9,1.15e+18,187.4,79.9,0.99\n")
    # found by the long run: a frame number in the billions made the tracker step through every frame
    @example(data=b"1,-1,281.9,100.0,187.4,79.9,0.99\n4398046511104,-1,281.9,100.0,187.4,79.9,0.99\n")
    def run(data: bytes) -> None:
        det = work / "det.txt"
        det.write_bytes(data)
        out = work / "out" / "tracks.txt"
        if out.exists():
            out.unlink()
        r = check_reader(
            "CLI: makeway track",
            lambda: runner.invoke(app, ["track", "--mot-det", str(det), "--out", str(out)]),
            allowed=(),
        )
        assert r is not None
        if r.exit_code == 0:
            assert out.is_file()
        else:
            _one_error_line(r, str(det))
            assert not out.exists()
        if out.parent.exists():  # no temporary left beside the output
            assert sorted(p.name for p in out.parent.iterdir()) in ([], ["tracks.txt"])

    run()


#: a freshness window of a day: a long fuzz run outlasts the default 10 s, and staleness is not the point
FRESH = ["--max-age-s", "86400"]


def test_fuzz_v2x_verify_through_the_cli(keys: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    """Fuzzed alert files through ``makeway v2x verify``: a verdict for each (exit 0 or 1), never an
    error; a changed message is never valid."""
    work = tmp_path_factory.mktemp("cli_verify")
    alert = work / "seed.bin"
    args = ["v2x", "alert", "--key", str(keys / "rsu.key"), "--lat", "59.437", "--lon", "24.754"]
    r = runner.invoke(app, [*args, "--heading-deg", "90", "--speed-mps", "12", "--out", str(alert)])
    assert r.exit_code == 0, r.output
    seed = alert.read_bytes()

    @budget(0.5)
    @given(data=mutated_bytes(seed) | st.binary(max_size=200))
    def run(data: bytes) -> None:
        msg = work / "msg.bin"
        msg.write_bytes(data)
        r = check_reader(
            "CLI: makeway v2x verify",
            lambda: runner.invoke(app, ["v2x", "verify", str(msg), "--trust", str(keys / "trust"), *FRESH]),
            allowed=(),
        )
        assert r is not None and r.exit_code in (0, 1), (r and r.exit_code, r and r.output)
        row = json.loads(r.stdout)
        assert row["valid"] is (data == seed) and r.exit_code == (0 if data == seed else 1)

    run()


def test_a_progress_bar_leaves_nothing_when_the_work_fails(capsys: pytest.CaptureFixture[str]) -> None:
    """A command that fails mid-run prints its error as the only line: the bar does not stay above it."""
    from makeway.progress import progress_bar

    with pytest.raises(InputError), progress_bar("reading", 10) as advance:
        advance(3)
        raise InputError("clip.mp4", "ends at frame 3 of 10 (truncated)")
    assert capsys.readouterr().err == ""
    with progress_bar("reading", 10) as advance:
        advance(10)
    assert "10/10" in capsys.readouterr().err  # a bar that finishes is shown
