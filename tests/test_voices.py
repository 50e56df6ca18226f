"""The compiled voice loop's bindings (`_core.Voices`, src/core/voices.cpp): the slot codes agree with the Python
side's, arrays of the wrong kind and slots holding impossible states are refused with an error (never a crash or a
write outside the arrays), and a stream loads no numba."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bowsynth import physics
from bowsynth import compiled as core
from bowsynth.engines.operator import voices as V
from bowsynth.engines.operator.bank import VoiceBank

from conftest import shipped_models, soft_bow_model

ROOT = Path(__file__).resolve().parents[1]


def bank(voices=2, block=64):
    return VoiceBank(44100, block, voices, "fdm", None, 100.0)


def make(b, **swap):
    """_core.Voices over the bank's arrays, with some tuple items swapped: swap={'ops': {3: array}}."""
    parts = dict(slots=(b.mode, b.pos, b.end, b.why), ops=b.ops, net=b.net, tb=b.tb, fdm=b.fdm, pit=b.pit)
    for name, items in swap.items():
        t = list(parts[name])
        for i, a in items.items():
            t[i] = a
        parts[name] = tuple(t)
    return core.load().Voices(parts["slots"], parts["ops"], parts["net"], parts["tb"], parts["fdm"], parts["pit"],
                              physics.NEWTON_TOL, physics.NEWTON_MAXIT)


def test_the_slot_codes_are_the_cores():
    c = core.load()
    for name in ("FREE", "OPERATOR", "FDM", "REST", "REST_COLS", "HELD", "CURVE", "LIVE", "WHY_OK", "WHY_FALLBACK",
                 "P_COLS"):
        assert getattr(V, name) == getattr(c, name), name
    assert V.P_RAMP + 1 == V.P_COLS


def test_the_bank_plays_an_fdm_note_and_frees_its_slot():
    b = bank()
    b.start_slot(1, 220.0, 0.1, 0.2, 100.0)
    b.start_fdm(1)
    b.end[1] = 100
    out, p = np.zeros(128), np.zeros(128)
    b.render(out, 0, 128, 1.0, outp=p)
    assert np.all(out[100:] == 0) and np.any(out[:100] != 0) and np.all(np.isfinite(p))
    assert b.mode[1] == V.FREE and b.mode[0] == V.FREE


@pytest.mark.parametrize("where, i, bad, error", [
    ("ops", 3, np.zeros((2, 3, 3)), TypeError),  # Bq float64, not float32
    ("ops", 3, np.zeros((2, 3, 6), np.float32)[:, :, ::2], TypeError),  # not contiguous
    ("slots", 1, np.zeros(2, np.int32), TypeError),
    ("fdm", 0, np.zeros((2, 6)), ValueError),  # fst: 7 columns
    ("fdm", 2, np.zeros((3, 3)), ValueError),  # vb_t: one row per slot
    ("pit", 1, np.zeros((2, 9)), ValueError),  # pp: P_COLS columns
    ("ops", 14, np.zeros((2, 4), np.float32), ValueError),  # qbuf: as long as the basis
    ("net", 8, np.ones((1, 2), np.bool_), ValueError),  # mask: square
    ("tb", 0, np.zeros((2, 0, 3)), ValueError),  # the trunk grid: >= 4 points
    ("tb", 4, -1.0, ValueError),  # the window
])
def test_wrong_arrays_are_refused(where, i, bad, error):
    with pytest.raises(error):
        make(bank(), **{where: {i: bad}})


def test_a_tuple_of_the_wrong_length_is_refused():
    b = bank()
    with pytest.raises(TypeError, match="ops"):
        core.load().Voices((b.mode, b.pos, b.end, b.why), b.ops[:-1], b.net, b.tb, b.fdm, b.pit, 1e-14, 60)


def test_render_refuses_a_block_outside_its_output():
    b = bank()
    with pytest.raises(ValueError, match="off"):
        b.render(np.zeros(10), 5, 6, 1.0)
    with pytest.raises(ValueError, match="outp"):
        b.render(np.zeros(10), 0, 10, 1.0, outp=np.zeros(9))
    with pytest.raises(TypeError):
        b.render(np.zeros(10, np.float32), 0, 10, 1.0)


@pytest.mark.parametrize("field, value, match", [
    ("mode", 7, "mode"),
    ("nvb", 4, "bow breakpoints"),
    ("stride", 0, "stride"),
    ("pos", -3, "negative"),
    ("spw", 50.0, "spw"),  # an operator slot whose window would overrun its buffer (3 samples)
    ("wstart", 5, "window"),
    ("rest_d", float("inf"), "rest flow"),  # a rest-flow slot with no linearisation (an overdamped one is fine)
    ("rest_r", float("nan"), "rest flow"),
    ("orig", 9, "partition"),  # the operator's windows would count from after the slot's position
])
def test_a_slot_holding_an_impossible_state_is_refused(field, value, match):
    b = bank()
    b.start_slot(0, 220.0, 0.1, 0.2, 100.0)
    b.start_fdm(0)
    if field in ("spw", "wstart", "rest_d", "rest_r", "orig"):
        b.mode[0] = V.REST if field.startswith(("rest", "orig")) else V.OPERATOR
        b.ops[1][0], b.ops[2][0] = 1.5, 1
    {"mode": lambda: b.mode.__setitem__(0, value), "nvb": lambda: b.fdm[4].__setitem__(0, value),
     "stride": lambda: b.fdm[1].__setitem__((0, 1), value), "pos": lambda: b.pos.__setitem__(0, value),
     "spw": lambda: b.ops[1].__setitem__(0, value), "wstart": lambda: b.ops[12].__setitem__(0, value),
     "rest_d": lambda: b.ops[17].__setitem__((0, V.R_D), value),
     "rest_r": lambda: b.ops[17].__setitem__((0, V.R_RADIUS), value),
     "orig": lambda: b.ops[18].__setitem__(0, value)}[field]()
    with pytest.raises(ValueError, match=match):
        b.render(np.zeros(64), 0, 64, 1.0)


def test_the_helpers_refuse_slots_and_arrays_they_were_not_given():
    b = bank()
    with pytest.raises(ValueError, match="out of range"):
        b.voices.to_fdm(2, 0.0, 0.0, 0)
    with pytest.raises(ValueError, match="trunk_basis"):
        b.voices.trunk_basis(0, 0.1, 2, 3)  # the FDM bank's buffer holds 3 samples
    with pytest.raises(ValueError, match="not an operator"):
        b.voices.advance_to(0, 10)
    with pytest.raises(ValueError, match="state"):
        V.dc_block(np.zeros(4), 4, 0.99, np.zeros(3), np.zeros(4, np.float32))
    with pytest.raises(ValueError, match="n values"):
        V.dc_block(np.zeros(4), 5, 0.99, np.zeros(2), np.zeros(4, np.float32))
    with pytest.raises(TypeError):
        V.dc_block(np.zeros(4, np.float32), 4, 0.99, np.zeros(2), np.zeros(4, np.float32))
    with pytest.raises(ValueError):
        V.pick_slot(np.zeros(2, np.int64), np.zeros(3, np.int64), np.zeros(2, np.int64), np.zeros(2, np.int64))


def test_the_dc_blocker_and_the_slot_picker():
    x = np.linspace(1.0, 2.0, 50)
    y, st = np.zeros(50, np.float32), np.zeros(2)
    V.dc_block(x[:20], 20, 0.9, st, y[:20])
    V.dc_block(x[20:], 30, 0.9, st, y[20:])  # in two calls, as blocks: the memory carries over
    ref, xp, yp = np.zeros(50), 0.0, 0.0
    for i in range(50):
        ref[i] = yp = x[i] - xp + 0.9 * yp
        xp = x[i]
    assert np.array_equal(y, ref.astype(np.float32))
    mode, end, pos, start = (np.array(a, np.int64) for a in ([1, 1, 1], [-1, 90, 50], [10, 80, 20], [5, 1, 3]))
    assert V.pick_slot(mode, end, pos, start) == 1  # the releasing voice nearest its end
    end[:] = -1
    assert V.pick_slot(mode, end, pos, start) == 1  # else the oldest
    mode[2] = V.FREE
    assert V.pick_slot(mode, end, pos, start) == 2


def test_a_stream_loads_no_numba():
    """What `bowsynth play` runs per callback, with a note, a bend, vibrato and a release: numba is no dependency."""
    code = ("import sys\nfrom bowsynth.live import Stream\n"
            f"s = Stream(block=512, voices=2, model={str(soft_bow_model().path)!r})\n"
            "for ev in ([(0, b'\\x90\\x45\\x40')], [(3, b'\\xe0\\x00\\x50'), (9, b'\\xb0\\x01\\x40')], [],"
            " [(7, b'\\x80\\x45\\x00')], [], []):\n"
            "    s.process(512, ev)\n"
            "assert s.counts['notes'] == 1\n"
            "print('numba' in sys.modules)\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


def test_the_banks_arrays_are_made_resident_without_changing_them():
    """VoiceBank touches every page of its slot arrays before any callback (a slot's first note paid for its page
    faults in the callback); the touch must leave every value as it was."""
    from bowsynth.engines.operator.bank import _resident

    rng = np.random.default_rng(0)
    arrays = [rng.standard_normal((3, 5000)), np.full(7, -1, np.int64), rng.standard_normal((2, 3, 4)).astype(np.float32),
              np.zeros(0), np.ones((4, 1), np.bool_)]
    before = [a.copy() for a in arrays]
    _resident(arrays)
    for a, b in zip(arrays, before):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("which", ["rotation", "rest-linearised"])
def test_a_live_voices_window_basis_is_the_offline_one(which):
    """The voice loop builds its window basis from the trunk grid in the core (Voices.trunk_basis, its linear rows by
    the rest flow's own step for a rest-linearised model); the offline rollout from numpy (window_basis): the same
    rows, to float32 rounding, and the same end-state rows."""
    from bowsynth.engines.operator.basis import numpy_operator
    from bowsynth.engines.operator.choose import SHIPPED_DIR
    from bowsynth.engines.operator.modelfile import load_model

    if which == "rotation":
        m = load_model(SHIPPED_DIR / "paper-fb100.safetensors")
    else:  # a shipped point model of the rest-linearised flow (NetConfig.rest_linear)
        rest = [m.path for m in shipped_models() if not m.domain.is_range and m.cfg.rest_linear]
        assert rest, "no shipped point model is rest-linearised"
        m = load_model(rest[0])
    assert (m.cfg.rest_linear and numpy_operator(m).lin is not None) == (which == "rest-linearised")
    b = VoiceBank(44100, 64, 1, "operator", m, 90.0)
    dtau = physics.dtau(147.3, 44100)
    spw, n_lo, Bq, Bp, endb, endlin = numpy_operator(m).window_basis(dtau)
    n_hi = Bq.shape[1]
    b.voices.trunk_basis(0, dtau, n_lo, n_hi)
    k3 = Bq.shape[0]
    assert np.abs(b.ops[3][0, :k3, :n_hi] - Bq).max() <= 1e-6 * np.abs(Bq).max()
    assert np.abs(b.ops[4][0, :k3, :n_hi] - Bp).max() <= 1e-6 * np.abs(Bp).max()
    assert np.abs(b.ops[5][0] - endb).max() <= 1e-9 * np.abs(endb).max()
    assert np.abs(b.ops[6][0] - endlin).max() <= 1e-12 * np.abs(endlin).max()
