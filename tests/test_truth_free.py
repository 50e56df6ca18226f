"""The operator plays on its own: a default render, a --pitch note, a gesture, a bow stop, a score with releases and the
live engine's tables run with every reference entry point raising (the compiled FDM loop, its wrapper, the render,
the batch and the sounding-ratio solve), from an empty cache, in real processes. The bows are drawn off the shipped
pitch map's grid."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from bowsynth.music import ratio_map

# run `bowsynth ARGS` with every FDM entry point replaced by one that raises (exit 99 and the call's name if reached)
WRAP = r"""
import sys, traceback
import bowsynth.compiled as C, bowsynth.engines.fdm as F, bowsynth.music.tuning as T
def boom(name):
    def f(*a, **k):
        sys.stderr.write(f"REFERENCE RAN: {name}\n" + "".join(traceback.format_stack(limit=12)))
        sys.stderr.flush()
        import os; os._exit(99)
    return f
for m, n in [(C, "fdm_run"), (F, "run_fdm_raw"), (F, "render_fdm"), (F, "fdm_batch"), (T, "measure_ratio")]:
    setattr(m, n, boom(n))
sys.argv = ["bowsynth"] + sys.argv[1:]
from bowsynth.cli.main import main
main()
"""


def run_truth_free(args, tmp_path, cache=None):
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "BOWSYNTH_CACHE": str(cache or tmp_path / "cache")}
    p = subprocess.run([sys.executable, "-c", WRAP, *map(str, args)], capture_output=True, text=True, env=env,
                       cwd=tmp_path, timeout=300)
    assert "REFERENCE RAN" not in p.stderr, p.stderr
    assert p.returncode == 0, p.stdout + p.stderr
    return p


def sounds(path: Path) -> bool:
    x, _ = sf.read(path)
    return bool(np.all(np.isfinite(x))) and float(np.std(x[len(x) // 2:])) > 1e-3 * float(np.max(np.abs(x)) + 1e-30)


def off_grid_bow(seed: int) -> tuple[float, float]:
    """A bow (F_B / w, v_B) between the map's grid points in both axes, inside the soft and stick-slip tiles."""
    rng = np.random.default_rng(seed)
    x, y = ratio_map.grid_axes()
    i, j = rng.integers(20, 50), rng.integers(30, 50)
    return float(math.exp(x[i] + 0.37 * (x[1] - x[0]))), float(ratio_map.vb_of(y[j] + 0.61 * (y[1] - y[0])))


@pytest.mark.parametrize("seed", [1, 2])
def test_a_default_render_of_a_held_bow_runs_no_reference(tmp_path, seed):
    beta, vb = off_grid_bow(seed)
    f0 = 150.0
    out = tmp_path / "a.wav"
    run_truth_free(["render", "--f0", f0, "--fb", beta * 2 * math.pi * f0, "--vb", vb, "-d", 1, out], tmp_path)
    assert sounds(out)


def test_a_pitch_render_is_tuned_from_the_shipped_map(tmp_path):
    out = tmp_path / "a4.wav"
    p = run_truth_free(["render", "--pitch", "A4", "--fb", 300, "-d", 1, out], tmp_path)
    assert "pitch 440.00 Hz" in p.stdout and sounds(out)


def test_a_gesture_and_a_bow_stop_run_no_reference(tmp_path):
    run_truth_free(["render", "--fb", "50@0,200@2", "--vb", 0.15, "-d", 2, tmp_path / "g.wav"], tmp_path)
    assert sounds(tmp_path / "g.wav")
    run_truth_free(["render", "--fb", 100, "--vb", "0.2@0,0.2@0.8,0@0.9", "-d", 1.2, tmp_path / "s.wav"], tmp_path)
    x, _ = sf.read(tmp_path / "s.wav")
    assert np.all(np.isfinite(x)) and np.std(x[: len(x) // 2]) > 0


def test_a_score_with_releases_runs_no_reference(tmp_path):
    melody = Path(__file__).resolve().parents[1] / "examples" / "melody.mid"
    run_truth_free(["score", "--score", melody, "--mix", tmp_path / "m.wav"], tmp_path)
    assert sounds(tmp_path / "m.wav")


def test_the_live_engines_tables_come_from_what_ships(tmp_path, monkeypatch):
    """The live engine's tuning tables (every velocity's f0 for every note, the ratio over the controllers' bows)
    are built with no reference run, and tune a note as the shipped map says."""
    import bowsynth.compiled as C
    import bowsynth.engines.fdm as F
    import bowsynth.music.tuning as T
    from bowsynth.live.tables import Tuning
    from bowsynth.music import midi as M
    from bowsynth.music.notes import midi_to_hz

    def boom(*a, **k):
        raise AssertionError("the reference ran")
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    for m, n in [(C, "fdm_run"), (F, "run_fdm_raw"), (F, "render_fdm"), (F, "fdm_batch"), (T, "measure_ratio")]:
        monkeypatch.setattr(m, n, boom)
    t = Tuning(100.0, 440.0, 44100)
    v, n = 64, 69
    beta, vb = M.bow_beta(v), M.bow_vb(v)
    want = midi_to_hz(n) / ratio_map.physics_ratio(beta, vb).r
    assert math.isclose(t.f0[v, n], want, rel_tol=1e-9)
    assert abs(1200 * math.log2(t.grid_ratio(beta, vb) / ratio_map.physics_ratio(beta, vb).r)) < 0.5


def test_the_shipped_map_is_the_reference_solve_within_a_hundredth_of_a_cent_off_its_grid():
    """The map against the solver at bows between its grid points, away from the band just above vb_stop (where a
    bow 0.01 % off moves the truth's pitch by cents)."""
    from bowsynth.music.tuning import sounding_ratio

    errs = []
    for seed in range(6):
        beta, vb = off_grid_bow(100 + seed)
        errs.append(1200 * math.log2(ratio_map.physics_ratio(beta, vb).r / sounding_ratio(beta, vb).r))
    assert np.median(np.abs(errs)) < 0.01 and np.max(np.abs(errs)) < 0.1, errs


def test_a_bow_stop_and_a_bow_off_the_map_are_answered_by_name():
    from bowsynth.music.tuning import SilentNoteError

    with pytest.raises(SilentNoteError, match="at or below 1/sqrt"):
        ratio_map.physics_ratio(1.0, 0.05)
    with pytest.raises(ratio_map.OffMapError, match="--method fdm"):
        ratio_map.physics_ratio(1.0, 0.2, 50.0)


def test_an_edited_map_is_refused_by_name(tmp_path):
    from bowsynth.errors import ModelFileError

    z = dict(np.load(ratio_map.MAP_PATH))
    z["r"] = z["r"] * 1.5  # ratios over 1: friction never raises the pitch
    np.savez(tmp_path / "m.npz", **z)
    with pytest.raises(ModelFileError, match="make tables"):
        ratio_map.RatioMap(tmp_path / "m.npz")
    (tmp_path / "t.npz").write_bytes(ratio_map.MAP_PATH.read_bytes()[:1000])
    with pytest.raises(ModelFileError, match="make tables"):
        ratio_map.RatioMap(tmp_path / "t.npz")


def test_a_bow_stop_no_model_covers_is_refused_unless_the_fdm_is_asked_for(monkeypatch):
    """A score's bow stop that no model covers is not handed to the FDM behind the user's back: one line naming the
    train command and --releases fdm; with --releases fdm (or --fallback fdm) the FDM plays it."""
    from bowsynth.engines.operator import choose
    from bowsynth.music.perform import render_notes
    from bowsynth.music.score import ScoreError, note_from_fields

    point = choose.as_model("paper-fb100")  # v_B 0.2 alone: it cannot play a bow stop
    monkeypatch.setattr(choose, "available_models", lambda: [point])
    note = note_from_fields("v", {"f0": 100.0, "beta": 0.159155, "vb": 0.2, "duration": 0.2}, "test")
    with pytest.raises(ScoreError, match="bow stop.*bowsynth train.*--releases fdm"):
        render_notes([note], model=point)
    (r,) = render_notes([note], model=point, releases="fdm")
    assert r.info.release == "fdm"
    (r,) = render_notes([note], model=point, fallback="fdm")
    assert r.info.release == "fdm"



def test_the_shipped_own_ratios_are_the_operators_measurements_of_the_shipped_models(tmp_path, monkeypatch):
    """own-ratios.json holds the shipped models' own sounding ratios at MIDI velocities' bows, keyed by model id (a
    retrained model matches none): every key names a shipped model, and a few entries measured afresh agree."""
    import json

    from bowsynth.engines.operator.choose import available_models
    from bowsynth.music import engine_ratio, model_ratio

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    ratios = json.loads(engine_ratio.SHIPPED_RATIOS.read_text())["ratios"]
    models = {m.key: m for m in available_models()}
    keys = list(ratios)
    assert len(keys) > 100 and all(k.split()[1] in models for k in keys)
    for k in keys[:: len(keys) // 4][:4]:
        engine, key, beta, vb, a = k.split()
        monkeypatch.setattr(engine_ratio, "shipped_ratios", lambda: {})
        monkeypatch.setattr(engine_ratio, "_ENGINE_RATIOS", {})
        fresh = model_ratio.own_ratio(models[key], float(beta), float(vb), float(a))
        # equal to float32 rounding: a model's cached bases and trunk grid, built earlier in the process by another
        # render's path, may round the last bits differently (1e-9 relative seen in the full suite)
        assert abs(1200 * math.log2(fresh / ratios[k])) < 1e-4, k


def test_a_note_asked_at_a_pitch_off_the_map_is_tuned_by_the_reference_for_the_fdm_to_play(tmp_path):
    """Another friction shape (a = 50) lies off the shipped map and no operator model plays it: a note asked at a
    pitch there is tuned with the reference's solve, and the FDM renders it."""
    from bowsynth.music.request import make_scene
    from bowsynth.music.tuning import sounding_pitch

    sc = make_scene(pitch="A4", fb=100.0, a=50.0)
    assert abs(1200 * math.log2(sounding_pitch(sc.f0, sc.fb, sc.vb, sc.a) / 440.0)) < 0.01
    p = subprocess.run([sys.executable, "-m", "bowsynth", "render", "--method", "fdm", "--a", "50", "--pitch", "A4",
                        "-d", "0.2", "-q", str(tmp_path / "a50.wav")], capture_output=True, text=True, timeout=120,
                       env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "BOWSYNTH_CACHE": str(tmp_path / "c")})
    assert p.returncode == 0 and (tmp_path / "a50.wav").exists(), p.stderr
