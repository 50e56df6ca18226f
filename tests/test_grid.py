"""Stick-slip voices on whole windows (engines/operator/grid.py): the stick-slip point models play at pitches where a
window is not a whole number of samples (before, they broke out of their cycle there), and the resampler that brings
the grid back to the asked rate keeps the signal."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from bowsynth import Scene, make_scene, render_fdm, render_operator
from bowsynth.metrics import listener_errors, note_sounds
from bowsynth import compiled as core
from bowsynth.engines.operator import grid
from bowsynth.engines.operator.basis import numpy_operator
from bowsynth.engines.operator.choose import SHIPPED_DIR, available_models, find_model
from bowsynth.engines.operator.modelfile import MAX_VALIDATION_HARM_DB, is_finite
from bowsynth.errors import DomainError

from conftest import CLAIM_MARGIN, centre_record, pitch_limit

# the shipped catalogue, read once: tests pick the models they are about from it by what they are
MODELS = [m for m in available_models() if m.path is not None and m.path.parent == SHIPPED_DIR]


def preset_model(preset):
    """The model the catalogue picks for a preset's scene."""
    return find_model(make_scene(preset), MODELS)


def test_stick_slip_bows_and_only_they_take_whole_windows():
    assert grid.needs_whole_windows(preset_model("paper-fb1000").domain)
    assert grid.needs_whole_windows(preset_model("scratch-g2").domain)
    assert not grid.needs_whole_windows(preset_model("paper-fb100").domain)
    # a range model whose box reaches just past the soft / stick-slip boundary (F_B / w 0.429 at stiffness 10): its
    # soft bows keep the output grid's windows, the sliver above the boundary takes whole ones
    straddling = [m.domain for m in MODELS if m.domain.is_range and m.domain.box[0] < 0.42 and 0.44 < m.domain.box[1]]
    assert straddling
    for d in straddling:
        assert grid.needs_whole_windows(d)
        assert not grid.needs_whole_windows(d, 0.42) and grid.needs_whole_windows(d, 0.44)
        assert grid.needs_whole_windows(d, 5.0)  # capped at the box's top


# The stick-slip models the catalogue plays at their own centre bow (find_model picks them there) and whose
# validation follows the note for no longer than these renders, at pitches where a window is not a whole number of
# samples: each is held to what its validation claims at that bow (conftest), plus what the grid adds. The pitch:
# pitch_limit plus GRID_CENTS (quarter-period windows are 12.5 samples at 880 Hz: a slow tile measured 1.5 cents
# beyond its claim there). The harmonics: the claim times CLAIM_MARGIN plus GRID_HARM_DB (locked-window tiles claim
# 0.002-0.02 dB and measure up to 0.05 here). The p range: the amplitude error the harmonic claim implies, times
# CLAIM_MARGIN, plus GRID_PTP (measured up to 1 %).
GRID_CENTS, GRID_HARM_DB, GRID_PTP = 1.5, 0.05, 0.03
RENDER_SECONDS = 1.5


def plays_at_its_centre(m) -> bool:
    d = m.domain
    if not grid.needs_whole_windows(d) or (m.meta.validation or {}).get("seconds", 0) > RENDER_SECONDS:
        return False
    sc = Scene(f0=440.0, fb=d.beta * 2 * math.pi * 440.0, vb=d.vb, a=d.a, duration=RENDER_SECONDS)
    try:
        return find_model(sc, MODELS) is m
    except DomainError:
        return False


GRID_MODELS = [m for m in MODELS if plays_at_its_centre(m)]


@pytest.mark.parametrize("m", GRID_MODELS, ids=[m.path.stem for m in GRID_MODELS])
@pytest.mark.parametrize("f0", [440.0, 880.0])
def test_a_stick_slip_model_plays_a_pitch_whose_window_is_not_whole_samples(m, f0):
    """Against the x100 FDM: the timbre, the pitch and the cycle's size within the model's claims, the onset within
    1 ms, no hand-over to the FDM (on the output grid's windows the same notes left the model's states:
    tests/test_fallback.py)."""
    d = m.domain
    sc = Scene(f0=f0, fb=d.beta * 2 * math.pi * f0, vb=d.vb, a=d.a, duration=RENDER_SECONDS)
    assert abs(numpy_operator(m).samples_per_window(sc.dtau) % 1 - 0.5) < 0.45  # not whole
    r = render_operator(sc, model=m)
    truth = render_fdm(sc, oversample=100)
    assert not r.method.fdm_fallback and not any("FDM" in n for n in r.info.notes), r.info.notes
    assert len(r.p) == sc.n_samples and r.p.dtype == np.float32 and np.isfinite(r.p).all()
    tail = slice(-sc.sample_rate // 2, None)
    if not note_sounds(truth.p):  # a bow that damps the mass: the truth rests, and so must the model
        assert not note_sounds(r.p[tail])
        return
    h = centre_record(m).get("harmonic_error_db")
    h = h if is_finite(h) else MAX_VALIDATION_HARM_DB
    harm = CLAIM_MARGIN * h + GRID_HARM_DB
    ptp_rel = CLAIM_MARGIN * (10 ** (h / 20) - 1) + GRID_PTP
    e = listener_errors(r.p, truth.p, sc.sample_rate, steady_seconds=0.75)
    assert e["harm_db_median"] < harm and abs(e["cents"]) < pitch_limit(m) + GRID_CENTS, e
    assert abs(e["onset_err_ms"]) < 1.0, e
    assert np.ptp(r.p[tail]) == pytest.approx(np.ptp(truth.p[tail]), rel=ptp_rel)


def test_the_stick_slip_tiles_take_quarter_period_windows():
    # a tile of bows that needs whole windows and whose windows are shorter than a period takes a quarter period
    tiles = [m for m in MODELS if grid.needs_whole_windows(m.domain) and numpy_operator(m).window < 1.9 * math.pi
             and m.domain.is_range]
    assert tiles
    for m in tiles:
        assert numpy_operator(m).window == pytest.approx(math.pi / 2), m.path.stem


def test_a_pitch_curve_on_a_stick_slip_model_is_refused_with_the_way_out():
    m = preset_model("paper-fb1000")
    d = m.domain
    f0 = [[0.0, 440.0], [0.5, 450.0]]
    fb = [[t, d.beta * 2 * math.pi * f] for t, f in f0]
    with pytest.raises(DomainError, match="stick-slip.*--method fdm"):
        render_operator(Scene(f0=f0, fb=fb, vb=d.vb, a=d.a, duration=0.5), model=m)


def test_the_grid_of_a_whole_window_is_the_scene_itself():
    sc = Scene(f0=100.0, fb=100.0, duration=0.1)
    inner, ratio = grid.whole_window_scene(sc, 441.0)
    assert inner is sc and ratio == 1


def test_the_grid_holds_whole_windows_and_covers_the_note():
    sc = Scene(f0=440.0, fb=100.0, duration=0.3)
    spw = 44100 / 440.0
    inner, ratio = grid.whole_window_scene(sc, spw)
    assert (sc.sample_rate, sc.duration) == (44100, 0.3)  # the asked scene is untouched
    assert inner.sample_rate / 440.0 == pytest.approx(math.ceil(spw), rel=1e-12)
    assert inner.dtau * math.ceil(spw) == pytest.approx(2 * math.pi, rel=1e-12)
    assert float(ratio) == pytest.approx(spw / math.ceil(spw), rel=1e-6)
    assert inner.n_samples * float(ratio) >= sc.n_samples + grid.PAD - 1


def grid_signal(f, ratio, n_out, phase=0.0, rate=44100.0):
    r = rate / float(ratio)
    t = np.arange(math.ceil((n_out + grid.PAD) / float(ratio))) / r
    return np.sin(2 * np.pi * f * t + phase)


@pytest.mark.parametrize("ratio", [Fraction(1297, 1307), Fraction(735, 748), Fraction(1260, 1261)])
def test_the_resampler_keeps_a_sine_up_to_10_khz(ratio):
    n = 20000
    t = np.arange(n) / 44100.0
    for f in (100.0, 4000.0, 10000.0):
        x = np.stack([grid_signal(f, ratio, n, 0.3), grid_signal(f, ratio, n)])
        y = grid.to_output(x, ratio, n)
        assert y.shape == (2, n) and y.dtype == np.float32
        body = slice(100, n - 100)
        assert np.max(np.abs(y[0, body] - np.sin(2 * np.pi * f * t[body] + 0.3))) < 1e-5
        # a note that starts from a moving state keeps its first samples (an odd continuation before them)
        assert np.max(np.abs(y[0, :100] - np.sin(2 * np.pi * f * t[:100] + 0.3))) < 1e-3


def test_a_stopped_row_does_not_spread_back_before_its_stop():
    ratio, n = Fraction(735, 748), 5000
    x = np.stack([grid_signal(500.0, ratio, n)] * 2)
    clean = grid.to_output(x, ratio, n)
    x[1, 3000:] = np.nan
    y = grid.to_output(x, ratio, n)
    cut = grid.from_grid(3000, ratio)
    assert 0 < cut < 3000 * float(ratio)
    np.testing.assert_array_equal(y[1, :cut], clean[1, :cut])
    np.testing.assert_array_equal(y[0], clean[0])
    assert np.isfinite(y).all()  # the caller marks [cut:] lost
    assert grid.from_grid(-1, ratio) == -1


def test_the_compiled_resampler_refuses_what_it_cannot_index():
    w, _ = grid._phases(3, 4)
    K = w.shape[1]
    y = np.zeros((1, 30), np.float32)
    x = np.ones((1, (29 * 4) // 3 + K))  # the last output's taps end at the last input
    core.polyphase(x, w, 3, 4, y)
    np.testing.assert_allclose(y, 1.0, rtol=1e-6)  # unit gain at DC in every phase
    with pytest.raises(ValueError, match="too short"):
        core.polyphase(x[:, :-1].copy(), w, 3, 4, y)
    with pytest.raises(ValueError, match="w has shape"):
        core.polyphase(x, w[:2], 3, 4, y)
    with pytest.raises(TypeError):
        core.polyphase(x.astype(np.float32), w, 3, 4, y)


@pytest.mark.parametrize("spw", [52.985, 52.9996, 40.0003], ids=["just-short", "a-hair-short", "just-over"])
def test_a_window_near_a_whole_number_of_samples_resamples_at_the_right_rate(spw):
    """A window just short of a whole number of samples made the rate ratio nearly 53 / 53, which no fraction of
    denominator <= 2000 holds better than 1/2000: the filter came up short of samples and the render failed with a
    ValueError (paper-fb1000 at 832.3 Hz). Now the grid takes the whole window whose ratio a fraction holds: it
    renders, its rate ratio within 1e-5 of the true one (0.02 cents), the pitch within 0.1 cent of a x100 FDM."""
    m = preset_model("paper-fb1000")
    d = m.domain
    f0 = 44100 / spw * numpy_operator(m).window / (2 * math.pi)
    sc = Scene(f0=f0, fb=d.beta * 2 * math.pi * f0, vb=d.vb, a=d.a, duration=1.0)
    inner, ratio = grid.whole_window_scene(sc, numpy_operator(m).samples_per_window(sc.dtau))
    assert abs(float(ratio) * inner.sample_rate / sc.sample_rate - 1) < 1e-5
    assert inner.n_samples >= (sc.n_samples + grid.PAD) / float(ratio)  # what the filter reads
    r = render_operator(sc, model=m)
    assert r.info.notes == [] and np.isfinite(r.p).all() and len(r.p) == sc.n_samples
    e = listener_errors(r.p, render_fdm(sc, oversample=100).p, sc.sample_rate, steady_seconds=0.5)
    assert abs(e["cents"]) < 0.1 and e["harm_db_median"] < 0.05, e


def test_a_voice_stopped_on_the_grid_is_finished_by_the_fdm_from_an_output_sample(monkeypatch):
    """A stop found on the grid (here the box check, made to fire at grid sample 10000) hands over on the output grid:
    the samples before the hand-over are the render's own, the FDM goes on from there, and nothing is lost or NaN."""
    from bowsynth.engines.operator import engine

    m = preset_model("paper-fb1000")
    d = m.domain
    sc = Scene(f0=440.0, fb=d.beta * 2 * math.pi * 440.0, vb=d.vb, a=d.a, duration=0.5)
    whole = render_operator(sc, model=m)
    monkeypatch.setattr(engine, "_box_exit", lambda m, g, q, p, window=None: 10000)
    with pytest.raises(DomainError, match="left the model's trained states"):
        render_operator(sc, model=m)
    r = render_operator(sc, model=m, fallback="fdm")
    assert any("finished with the FDM" in n for n in r.info.notes) and r.method.fdm_fallback
    assert len(r.p) == sc.n_samples and np.isfinite(r.p).all() and np.isfinite(r.q).all()
    inner, ratio = grid.whole_window_scene(sc, numpy_operator(m).samples_per_window(sc.dtau))
    cut = grid.from_grid(10000, ratio) - 1  # the FDM starts from the last sample before the stop
    assert 9000 < cut < 10000
    assert float(r.info.notes[0].split("t = ")[1].split(" s")[0]) == pytest.approx((cut + 1) / sc.sample_rate, abs=1e-4)
    np.testing.assert_array_equal(r.p[:cut + 1], whole.p[:cut + 1])
    step = np.max(np.abs(np.diff(whole.p)))  # the join is no larger a jump than the render's own steps
    assert abs(float(r.p[cut + 1]) - float(r.p[cut])) <= 1.5 * step
    # the FDM's continuation stays on the stick-slip cycle's scale
    assert np.ptp(r.p[-4410:]) == pytest.approx(np.ptp(whole.p[-4410:]), rel=0.1)


@pytest.mark.parametrize("ratio", [Fraction(735, 748), Fraction(3, 5), Fraction(5, 4)])
def test_the_one_pass_resampler_holds_continues_and_filters_as_numpy_does(ratio):
    # a grid's own ratio (23 taps, eight outputs a product between the phase's wraps), one with 35 taps, and one
    # that reads no eight consecutive inputs (upsampling: every output on its own)
    n = 3000
    up, down = ratio.numerator, ratio.denominator
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.standard_normal((3, math.ceil((n + grid.PAD) / float(ratio)))), axis=1).astype(np.float32)
    x[1, 2000:] = np.nan  # a voice stopped on the grid: held at its last finite sample
    x[2, 0] = np.inf  # not finite from its first sample on: zeros
    w, k0 = grid._phases(up, down)
    # the same in numpy: the row held, an odd continuation of k0 samples at both ends, in float64; then the filter
    ref = x.astype(np.float64)
    for r in ref:
        lost = np.flatnonzero(~np.isfinite(r))
        if lost.size:
            r[lost[0]:] = r[lost[0] - 1] if lost[0] else 0.0
    xp = np.concatenate([2 * ref[:, :1] - ref[:, k0:0:-1], ref, 2 * ref[:, -1:] - ref[:, -2:-k0 - 2:-1]], axis=1)
    want = np.empty((3, n), np.float32)
    core.polyphase(np.ascontiguousarray(xp), w, up, down, want)
    got = grid.to_output(x, ratio, n)
    # the one-pass loop sums in float32 (the network's precision), the oracle in float64: a few float32 roundings
    # of the row's scale apart, at every sample, the ends and the held stretch included (a tap's weight lost or
    # shifted by one sample would be ~1e-2 of it)
    scale = np.max(np.abs(ref), axis=1, keepdims=True)
    assert np.all(np.abs(got - want) <= 2e-6 * scale)
    assert np.all(got[2] == 0.0) and np.isfinite(got).all()
    with pytest.raises(ValueError, match="too short"):
        core.resample_rows(x, w, k0, up, down, np.empty((3, 2 * n), np.float32))


@pytest.mark.parametrize("ratio", [Fraction(441, 442), Fraction(735, 748), Fraction(3, 5)])
def test_the_resampler_in_place_writes_what_it_writes_elsewhere(ratio):
    # a render's rows are resampled over themselves (no fresh array): the same bits as into a new one, a stopped
    # row's hold and both ends included, over more than one of the loop's chunks of 4096 outputs
    n = 9000
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.standard_normal((2, math.ceil((n + grid.PAD) / float(ratio)))), axis=1).astype(np.float32)
    x[1, 7000:] = np.nan
    want = grid.to_output(x, ratio, n)
    rows = [x[0].copy(), x[1].copy()]
    got = grid.to_output_in_place(rows, ratio, n)
    for g, r, wnt in zip(got, rows, want):
        assert np.shares_memory(g, r)
        np.testing.assert_array_equal(g, wnt)


def test_the_resampler_refuses_an_overlap_it_cannot_compute_in_place():
    w, k0 = grid._phases(5, 4)  # upsampling: an output reads inputs behind its own index
    x = np.zeros((1, 400), np.float32)
    with pytest.raises(ValueError, match="overlap"):
        core.resample_rows(x, w, k0, 5, 4, x[:, :300])
    w, k0 = grid._phases(3, 4)
    flat = np.zeros(800, np.float32)
    with pytest.raises(ValueError, match="overlap"):  # two rows: the second row's outputs land on the first's inputs
        core.resample_rows(flat.reshape(2, 400), w, k0, 3, 4, flat[:580].reshape(2, 290))
    with pytest.raises(ValueError, match="overlap"):  # one row, its output a sample later than its input
        core.resample_rows(flat[:399].reshape(1, 399), w, k0, 3, 4, flat[1:291].reshape(1, 290))
    core.resample_rows(flat[:400].reshape(1, 400), w, k0, 3, 4, flat[400:690].reshape(1, 290))  # apart: fine
    core.resample_rows(flat[:400].reshape(1, 400), w, k0, 3, 4, flat[:290].reshape(1, 290))  # its own row: fine
