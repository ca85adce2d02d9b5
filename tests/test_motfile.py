"""MOTChallenge file reading/writing and its error messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from makeway.errors import InputError
from makeway.sense.motfile import read_mot, write_mot_tracks


def test_reads_real_detections(mot15_root: Path) -> None:
    d = read_mot(mot15_root / "TUD-Stadtmitte" / "det" / "det.txt")
    assert len(d) == 951 and d.num_frames == 179
    assert (np.diff(d.frames) >= 0).all() and (d.xywh[:, 2:] > 0).all()
    frames = list(d.by_frame())
    assert len(frames) == 179 and sum(len(r) for _, r in frames) == 951
    gt = read_mot(mot15_root / "TUD-Stadtmitte" / "gt" / "gt.txt", kind="gt")
    assert len(np.unique(gt.ids)) == 10


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("1,-1,10,10,5\n", "line 1: expected at least 6 values"),
        ("1,-1,10,10,5,5,0.9\n2,-1,a,10,5,5,0.9\n", "line 2: non-numeric"),
        ("0,-1,10,10,5,5,0.9\n", "frame must be a positive integer"),
        ("1,-1,10,10,-5,5,0.9\n", "width and height must be positive"),
        ("1,-1,10,nan,5,5,0.9\n", "NaN"),
    ],
)
def test_malformed_rows(tmp_path: Path, content: str, needle: str) -> None:
    f = tmp_path / "det.txt"
    f.write_text(content)
    with pytest.raises(InputError, match=needle) as err:
        read_mot(f)
    assert "det.txt" in str(err.value)


def test_missing_folder_binary_and_duplicates(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        read_mot(tmp_path / "nope.txt")
    with pytest.raises(InputError, match="is a folder"):
        read_mot(tmp_path)
    b = tmp_path / "bin.txt"
    b.write_bytes(b"\xff\xfe\x00\x81" * 50)
    with pytest.raises(InputError, match="not a text file"):
        read_mot(b)
    g = tmp_path / "gt.txt"
    g.write_text("1,3,0,0,5,5,1\n1,3,9,9,5,5,1\n")
    with pytest.raises(InputError, match="id 3 appears more than once in frame 1"):
        read_mot(g, kind="gt")
    assert len(read_mot(g)) == 2  # detections may repeat ids (-1)


def test_write_round_trip(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "tracks.txt"
    write_mot_tracks(out, [(1, 1, 10.0, 20.0, 30.0, 40.0), (2, 1, 11.0, 21.0, 30.0, 40.0)])
    assert out.read_text().splitlines()[0] == "1,1,10.00,20.00,30.00,40.00,1,-1,-1,-1"
    back = read_mot(out, kind="tracks")
    assert back.num_frames == 2 and back.ids.tolist() == [1, 1]
    assert list(out.parent.iterdir()) == [out]  # no temporary files left
