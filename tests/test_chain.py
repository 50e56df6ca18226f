"""A bow that crosses from one model's box into another's (engines/operator/chain.py): the shipped tiles play it in
turn, each from the state the one before left, handed over inside the boxes' overlaps; against the truth it sounds
like one model would."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from conftest import shipped_models, shipped_pick
from hypothesis import strategies as st

from bowsynth import Scene, render_fdm, render_operator
from bowsynth.metrics import frame_errors, listener_errors
from bowsynth.controls import Curve, between
from bowsynth.engines.operator.chain import EDGE, LOOKS_PER_PERIOD, MIN_SEGMENT, _depths, chain_plan
from bowsynth.engines.operator.choose import available_models, covering_model
from bowsynth.errors import DomainError

W = 2 * math.pi * 100


def crescendo(top: float = 1.2, seconds: float = 2.0, vb=0.2) -> Scene:
    """The listener benchmark's crescendo from the soft bow into stick-slip (F_B / w 0.1 -> top over 0.3-1.8 s)."""
    return Scene(f0=100, fb=[(0.3, 0.1 * W), (1.8, top * W)], vb=vb, duration=seconds)


def test_between_cuts_a_curve_to_its_stretch():
    c = Curve(((0.0, 1.0), (1.0, 3.0), (2.0, 0.0)))
    cut = between(c, 0.5, 1.5)
    assert cut.points == ((0.0, 2.0), (0.5, 3.0), (1.0, 1.5))  # the values at the cuts, the breakpoint inside
    assert cut.at(5.0) == pytest.approx(1.5)  # held after the stretch: its range is the stretch's own
    assert between(c, 1.2, 1.8).lo == pytest.approx(0.6) and between(4.0, 1.0, 2.0) == 4.0


def test_plan_hands_each_stretch_to_a_model_that_plays_its_bows():
    sc = crescendo()
    plan = chain_plan(sc, available_models())
    assert plan is not None and len(plan) >= 3
    starts = [s for s, _ in plan]
    assert starts[0] == 0 and all(b > a for a, b in zip(starts, starts[1:]))
    assert all(m1 is not m2 for (_, m1), (_, m2) in zip(plan, plan[1:]))
    ends = starts[1:] + [sc.n_samples]
    t = np.arange(sc.n_samples) / sc.sample_rate
    beta, vb = sc.fb_at(t) / sc.omega, sc.vb_at(t)
    look = int(sc.sample_rate / (sc.f0 * LOOKS_PER_PERIOD)) + 1
    prev = None
    for (s, m), e in zip(plan, ends):
        assert m.failure is None and m.domain.box_contains(beta[s:e], vb[s:e]).all(), m.path.stem
        if prev is not None:  # a hand-over away from the new box's edges, or where the old box ends
            deep = _depths(m, beta[s:s + 1], vb[s:s + 1])[0] >= EDGE
            ends_here = not prev.domain.box_contains(beta[min(s + look, sc.n_samples - 1)], vb[s])
            assert deep or ends_here, (s, m.path.stem)
        assert e - s >= MIN_SEGMENT * sc.sample_rate or e == sc.n_samples
        prev = m
    # the stick-slip end is a stick-slip tile's
    assert plan[-1][1].domain.box[0] >= 0.6


def test_no_chain_for_a_held_bow_or_a_bow_no_model_plays():
    models = available_models()
    assert chain_plan(Scene(f0=100, fb=0.3 * W, vb=0.2, duration=1.0), models) is None
    beyond = crescendo(top=3.0)  # F_B / w 3 is in no box: no chain, the usual refusal naming the bow
    assert chain_plan(beyond, models) is None
    with pytest.raises(DomainError, match="no model covers"):
        render_operator(beyond)


def test_a_crescendo_into_stick_slip_plays_through_the_tiles_like_the_truth():
    sc = crescendo()
    r = render_operator(sc)
    assert r.method == "operator" and not r.method.fdm_fallback
    assert r.info.chain and len(r.info.chain) >= 3
    assert "played by" in r.info.notes[0] and r.info.chain[-1][1] in r.info.notes[0]
    assert np.isfinite(r.p).all() and r.p.dtype == np.float32
    truth = render_fdm(sc, oversample=20)
    fe = frame_errors(r.p, truth.p, sc.sample_rate)
    err = np.column_stack([fe["t"], fe["harm_db"], fe["cents"]])
    assert np.median(err[:, 1]) < 0.5 and np.median(err[:, 2]) < 3.0, err
    assert err[:, 1].max() < 4.0, err  # no hand-over glitch a frame would hear
    stick = err[err[:, 0] >= 1.2]  # in stick-slip, where only the tiles play
    assert np.median(stick[:, 1]) < 0.3 and np.median(stick[:, 2]) < 3.0, stick
    # the controls it applied are each stretch's model's: the crescendo, per window
    assert np.allclose(r.controls["fb"][-10:], 1.2 * W, rtol=1e-3)


def test_a_model_named_plays_alone_and_a_batch_voice_says_which():
    sc = crescendo(seconds=1.2)
    named = chain_plan(sc, available_models())[-1][1].path.stem  # a model that plays the end of the bow, not all of it
    with pytest.raises(DomainError):
        render_operator(sc, model=named)  # asked for by name: no chain behind the user's back
    held = Scene(f0=100, fb=0.2 * W, vb=0.2, duration=0.5)
    a, b = render_operator([held, sc])
    assert a.info.chain is None and b.info.chain
    assert b.info.notes[0].startswith("note: voice 2: no one model covers")


def said_in_turn(text: str, names: list[str]) -> bool:
    """Whether the names appear in the text in this order."""
    at = 0
    for name in names:
        at = text.find(name, at)
        if at < 0:
            return False
        at += len(name)
    return True


def test_the_cli_says_which_models_played(tmp_path):
    out = tmp_path / "c.wav"
    fb = f"{0.1 * W:.3f}@0.3,{1.2 * W:.3f}@1.8"
    p = subprocess.run([sys.executable, "-m", "bowsynth", "render", "--fb", fb, "--vb", "0.2", "-d", "2", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    plan = chain_plan(crescendo(), available_models())  # the bow it was given, as chain_plan plays it
    assert f"played by {len(plan)} models in turn" in p.stdout, p.stdout
    assert said_in_turn(p.stdout, [f"{m.path.stem} from" for _, m in plan]), p.stdout
    assert out.stat().st_size > 0


def test_a_stretch_that_fails_says_where_and_fallback_fdm_finishes_the_note(monkeypatch):
    from bowsynth.engines.operator import chain

    sc = crescendo(seconds=1.2)
    plan = chain_plan(sc, available_models())

    def refuse(seg, m, lock=None):  # a model that leaves its states in its stretch: the engine's error, in its times
        raise DomainError("the rollout left the model's trained states at t = 0.0100 s")
    with pytest.raises(DomainError, match=rf"{plan[0][1].path.stem}, in its stretch from t = 0.000 s: the rollout"):
        chain.render_chain(sc, plan, refuse)
    monkeypatch.setattr(chain, "render_chain", lambda *a, **k: refuse(None, None))
    with pytest.raises(DomainError):
        render_operator(sc)
    r = render_operator(sc, fallback="fdm")  # the model that plays the opening longest, the FDM the rest
    assert r.method.fdm_fallback and r.info.chain is None and np.isfinite(r.p).all()


def test_a_score_note_that_crosses_boxes_is_played_not_refused(tmp_path):
    score = tmp_path / "into.toml"
    score.write_text('[[voice]]\nname = "cresc"\nf0 = 100.0\nvb = 0.2\nduration = 2.0\n'
                     f'fb = [[0.3, {0.1 * W:.3f}], [1.8, {1.5 * W:.3f}]]\n')
    out = tmp_path / "into.wav"
    p = subprocess.run([sys.executable, "-m", "bowsynth", "score", "--score", str(score), "--mix", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    from bowsynth.music.score import load_score

    [note] = load_score(score)
    plan = chain_plan(note.rollout_scene(), available_models())
    assert "played by" in p.stdout and " -> ".join(m.path.stem for _, m in plan) in p.stdout, p.stdout
    assert out.stat().st_size > 0
    # its bow stop at F_B / w 1.5 (v_B from 0.2 to 0), by the operator: the model that covers the stop's bows
    stop = Scene(f0=100, fb=1.5 * W, vb=[(0.0, 0.2), (note.release, 0.0)], duration=note.scene.duration - note.hold)
    by = covering_model(stop, available_models())
    assert by is not None and "bow stops: 1 by the operator, 0 by the FDM" in p.stdout, p.stdout
    assert f"{by.id} ({by.path})" in p.stdout, p.stdout  # the models used: the stop's among them


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.floats(0.0, 2.0), st.floats(0.05, 1.9), st.floats(0.09, 0.26)), min_size=2, max_size=4),
       st.floats(65.0, 880.0), st.floats(0.3, 2.0))
def test_any_moving_bow_gets_a_plan_whose_stretches_its_models_play_or_none(points, f0, seconds):
    """Random bow curves over the playing space: a plan's stretches start at 0, increase, and each model plays every
    sample of its stretch; a render of it sounds (finite) or stops with one DomainError, never anything else."""
    points = sorted({round(t, 3): (t, b, v) for t, b, v in points}.values())
    if len(points) < 2:
        return
    w = 2 * math.pi * f0
    sc = Scene(f0=f0, fb=[(t, b * w) for t, b, _ in points], vb=[(t, v) for t, _, v in points], duration=seconds)
    plan = chain_plan(sc, available_models())
    if plan is None:
        return
    starts = [s for s, _ in plan]
    assert starts[0] == 0 and all(b > a for a, b in zip(starts, starts[1:]))
    t = np.arange(sc.n_samples) / sc.sample_rate
    beta, vb = sc.fb_at(t) / w, sc.vb_at(t)
    for (s, m), e in zip(plan, starts[1:] + [sc.n_samples]):
        assert m.domain.box_contains(beta[s:e], vb[s:e]).all()
    try:
        r = render_operator(sc)
    except DomainError as e:
        assert "\n" not in str(e)
    else:
        assert np.isfinite(r.p).all() and r.info.chain


def test_the_papers_stick_slip_note_stops_on_the_operator():
    """The paper's stick-slip scene (F_B 1000 at f0 100, F_B / w 1.59) with its bow stopped: one model covers its
    held bow and its stop down to v_B 0, and plays it whole, as the truth: the held part's timbre and pitch, the
    stop's envelope, and the mass at rest at the end."""
    sc = Scene(f0=100.0, fb=1000.0, vb=[[0.0, 0.2], [0.6, 0.2], [0.8, 0.0]], duration=1.2)
    from bowsynth.api import render

    pick = shipped_pick(sc)  # (raises where no model covers the whole note)
    r = render(sc, windows="auto")  # free windows play the model's own period there: 3.8 cents sharp
    assert r.info.model_path == str(pick.path) and r.info.chain is None and not r.method.fdm_fallback
    truth = render_fdm(sc, oversample=100)
    held = slice(int(0.2 * 44100), int(0.6 * 44100))
    e = listener_errors(r.p[held], truth.p[held], 44100)
    assert e["harm_db_median"] < 0.5 and abs(e["cents"]) < 1.0, e  # measured 0.05 dB, 0.0003 cents per 100 ms frame
    n = 2205  # 50 ms frames from the stop's start: the note dies as the truth's does
    for a in range(int(0.6 * 44100), int(0.9 * 44100), n):
        got, ref = np.std(r.p[a:a + n]), np.std(truth.p[a:a + n])
        assert abs(20 * np.log10(got / ref)) < 1.0, (a / 44100, got, ref)
    assert np.abs(r.p[-441:]).max() < 1e-3 * np.abs(truth.p).max()


def test_a_held_note_that_stops_at_the_space_edge_plays_through_the_tiles_and_locks_its_held_stretch():
    """F_B / w 2.0 held at v_B 0.12, stopped over 50 ms, at 440 Hz: no one model covers it (the stop ends below the
    held bow's model's v_B), so it chains, from the model picked for the held bow to the one picked where the bow has
    stopped. The held bow's model locks its stretch to the physics' period (free, it played 5.0 cents off per 100 ms
    frame, measured) and the note rests after the stop, as the truth does."""
    from bowsynth.api import render

    f0 = 440.0
    fb = 2.0 * 2 * math.pi * f0
    sc = Scene(f0=f0, fb=fb, vb=[(1.0, 0.12), (1.05, 0.0)], duration=1.6)
    held, stopped = (shipped_pick(Scene(f0=f0, fb=fb, vb=vb, duration=1.0)).path.stem for vb in (0.12, 0.0))
    r = render(sc, windows="auto")
    assert r.info.chain and r.info.chain[0][1] == held and r.info.chain[-1][1] == stopped, r.info.chain
    truth = render_fdm(sc, oversample=20)
    fe = frame_errors(r.p, truth.p, sc.sample_rate)
    assert fe["cents_median"] < 0.2 and fe["harm_db_median"] < 0.2, fe
    free = frame_errors(render(sc, windows="free").p, truth.p, sc.sample_rate)
    assert free["cents_median"] > 1.0, free
    tail = r.p[int(1.3 * sc.sample_rate):]
    assert np.ptp(tail) < 1e-3 * np.ptp(r.p)  # at rest (a creep of the mass to the bow's rest point, no sound)
