"""Issue 4: more than one siren — time–frequency bin assignment (makeway.perceive.audio.multisource)
and SirenModel.sources with it, on recordings simulated from held-out real ingredients."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.multisource import SourceSeparator
from makeway.perceive.audio.siren_model import MAX_SOURCES, NEAR_ALONE_M, SirenModel
from makeway.sense.recording import Recording, reference_mics
from makeway.sim.audio_scenarios import simulate_recording
from makeway.sim.siren import load_siren_sources, split_sources

TOL = math.radians(15.0)


def _near(a: float, b: float) -> bool:
    return abs(math.remainder(a - b, 2.0 * math.pi)) <= TOL


def _held_out(data_root: Path, scenario: str, seed: int, n_sirens: int) -> Recording:
    from makeway.sim.acoustics import load_street_noise_sources

    return simulate_recording(
        scenario,
        6.0,
        seed=seed,
        siren="real",
        n_sirens=n_sirens,
        siren_pool=split_sources(load_siren_sources(data_root), "test"),
        noise_pool=split_sources(load_street_noise_sources(data_root), "test"),
        data_root=data_root,
    )


@pytest.fixture(scope="module")
def two_sirens(data_root: Path) -> tuple[np.ndarray, np.ndarray]:
    """Windows of a two-EV recording where both sirens are within 50 m and ≥ 30° apart, and the
    two true bearings of each."""
    rec = _held_out(data_root, "random", 2, 2)
    lab = label_recording(rec)
    both = lab.present.all(axis=1)
    theta = np.where(both[:, None], lab.theta, 0.0)
    dist = np.where(both[:, None], lab.distance, np.inf)
    apart = np.abs(np.remainder(theta[:, 0] - theta[:, 1] + np.pi, 2 * np.pi) - np.pi) >= math.radians(30)
    sel = both & (dist.max(axis=1) <= 50.0) & apart
    assert sel.sum() >= 20
    return window_batch(rec, lab)[sel], theta[sel]


@pytest.fixture(scope="module")
def one_siren(data_root: Path) -> tuple[np.ndarray, np.ndarray]:
    rec = _held_out(data_root, "opposite_direction", 15, 1)
    lab = label_recording(rec)
    sel = lab.siren & lab.kept
    return window_batch(rec, lab)[sel], lab.theta[sel, 0]


def test_separator_finds_both_sirens(two_sirens: tuple[np.ndarray, np.ndarray]) -> None:
    wins, truth = two_sirens
    sep = SourceSeparator(reference_mics(), 48000)
    found = [sep.bearings(w) for w in wins]
    both = [all(any(_near(b, t) for b in f) for t in th) for f, th in zip(found, truth, strict=True)]
    # 21 of 33 windows on this recording (2026-11-22); the network's bearing map found ~1 % of such
    # windows on training recordings
    assert np.mean(both) >= 0.5
    assert all(len(f) <= 3 for f in found)
    for f in found:  # reported bearings are distinct by the separation
        for i in range(len(f)):
            for j in range(i):
                assert abs(math.remainder(f[i] - f[j], 2 * math.pi)) >= math.radians(30) - 1e-9


def test_separator_one_siren_gives_one_bearing(one_siren: tuple[np.ndarray, np.ndarray]) -> None:
    wins, truth = one_siren
    sep = SourceSeparator(reference_mics(), 48000)
    firsts = [sep.bearings(w)[:1] for w in wins]
    # 56 % on this pass-by (2026-11-22): the assignment's first bearing is often a lobe of the
    # siren, which is why the network, not the separator, reports the nearest siren
    assert np.mean([bool(f) and _near(f[0], t) for f, t in zip(firsts, truth, strict=True)]) >= 0.5
    # through the model (network nearest + separator): a second siren here is a spurious one; the
    # pass at 4–9 m, where the siren's bearing sweeps within a window, reports none (NEAR_ALONE_M)
    model = SirenModel(threads=2)
    pred = model.predict(wins)
    found = [model.sources(pred, i, w) for i, w in enumerate(wins)]
    # benchmark (bench_audio_multisource.py): a spurious second siren in 1.2 % of 480 held-out
    # one-siren windows with the siren checks of SourceSeparator.further (5.8 % without them).
    # Bound on these 27 windows: ≤ 2; at 1.2 % the chance of 3 or more is 0.4 % (binomial), so a
    # failure means the rate itself has grown (at the unchecked 5.8 % it would be 20 %)
    assert len(wins) == 27
    assert sum(len(f) >= 2 for f in found) <= 2
    assert all(len(f) <= 1 for i, f in enumerate(found) if pred.distance[i] < NEAR_ALONE_M)


def test_separator_errors_and_silence() -> None:
    sep = SourceSeparator(reference_mics(), 48000)
    with pytest.raises(ValueError, match="window must be"):
        sep.bearings(np.zeros((4, 24000)))
    with pytest.raises(ValueError, match="mics must be"):
        SourceSeparator(np.zeros((8, 2)), 48000)
    assert sep.bearings(np.zeros((8, 24000))) == []  # no bin stands out
    assert sep.responses(np.zeros((8, 500))).shape == (0, sep.n_azimuth)  # shorter than one frame


def test_model_sources_reports_further_sirens(two_sirens: tuple[np.ndarray, np.ndarray]) -> None:
    wins, truth = two_sirens
    model = SirenModel(threads=2)
    pred = model.predict(wins)
    n_two = 0
    for i, w in enumerate(wins):
        plain = model.sources(pred, i)
        full = model.sources(pred, i, w)
        if pred.prob[i] < model.threshold:
            assert plain == [] and full == []
            continue
        assert plain == full[:1] and plain[0]["bearing_rad"] == float(pred.theta[i])
        assert plain[0]["distance_m"] == float(pred.distance[i])
        assert len(full) <= MAX_SOURCES and [s["rank"] for s in full] == list(range(len(full)))
        assert all(s["distance_m"] is None for s in full[1:])
        if len(full) >= 2 and all(any(_near(s["bearing_rad"], t) for s in full) for t in truth[i]):
            n_two += 1
    # 21 of 33 (22 without the siren checks of SourceSeparator.further, which judge each further
    # source's own bins with the siren network)
    assert n_two >= 0.4 * len(wins)


@pytest.fixture(scope="module")
def street_noise_rec(data_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Recording:
    """Issue 21, item 9: recording 0 of ``makeway audio simulate --n 2 --split test`` — one siren
    closing from behind, and the held-out ``traffic-4`` street recording as a point source 25 m away
    at −54°, while the siren is 30–80 m off."""
    from makeway.sense.recording import read_recording
    from makeway.sim.audio_scenarios import generate_recordings, source_pools

    sirens, noise = source_pools("test", data_root)
    out = tmp_path_factory.mktemp("street_noise")
    (folder,) = generate_recordings(out, 1, seed=0, siren_pool=sirens, noise_pool=noise, progress=False)
    return read_recording(folder)


def test_listen_reports_no_street_noise_source_as_a_siren(street_noise_rec: Recording) -> None:
    from makeway.perceive.audio.stream import SirenListener, listen

    rec = street_noise_rec
    meta = rec.meta
    assert len(meta["sirens"]) == 1 and not meta["distractors"]
    noise_bearings = [math.atan2(p[1], p[0]) for p in meta["street_noise"]["positions_vehicle_m"]]
    lab = label_recording(rec)
    model = SirenModel(threads=2)
    msgs = list(listen(rec, model=model))
    assert len(msgs) == len(lab)
    hops = [i for i, m in enumerate(msgs) if m["is_siren"]]
    assert len(hops) >= 0.9 * len(msgs)  # the siren sounds throughout
    # the one siren is reported, at its true bearing in most hops (the network's own accuracy: 49
    # of 56 hops within 15°; most misses are the pass at 5–8 m, where the bearing sweeps)
    on_target = [_near(msgs[i]["sources"][0]["bearing_rad"], lab.theta[i, 0]) for i in hops]
    assert np.mean(on_target) >= 0.8
    # and nothing else: without the siren checks of SourceSeparator.further, 22 of the 56 hops
    # here report a second siren, 19 of them at the street-noise source at −54°
    assert all(len(msgs[i]["sources"]) == 1 for i in hops)

    # the recording does provoke it: without the checks the assignment reports the street noise
    # in 19 hops, within 15° of one of the two noise sources
    listener = SirenListener(rec.mics, rec.sample_rate, model=model, full_scale_db_spl=rec.full_scale_db_spl)
    assert listener.separator is not None
    listener.separator.check_siren = False
    win = listener.window_samples
    audio = np.asarray(rec.audio)
    at_noise = 0
    for start, t_end in zip(lab.start, lab.t_end, strict=True):
        obs = listener.step(audio[start : start + win].T, float(t_end)).to_json()
        at_noise += any(_near(s["bearing_rad"], b) for s in obs["sources"][1:] for b in noise_bearings)
    assert at_noise >= 10
