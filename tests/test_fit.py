"""bowsynth fit: the bow that made a held note, found through the operator; the surrogate's values and gradients;
the loss's invariances; and every target it must refuse, in real processes."""

from __future__ import annotations

import math
import subprocess
import sys
import tomllib

import numpy as np
import pytest
import soundfile as sf

from bowsynth import physics
from bowsynth.fit.surrogate import note_scene
from test_report import browser, check_page, open_report  # noqa: F401  (the report tests' browser and checks)


def bow(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "bowsynth", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600)


def one_line(p):
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    return lines[0]


@pytest.fixture(scope="module")
def held_target(tmp_path_factory):
    """A held note rendered by `bowsynth render` (the operator): 1 s at f0 180, F_B / w 1.1, v_B 0.19."""
    d = tmp_path_factory.mktemp("fit")
    f0, beta, vb = 180.0, 1.1, 0.19
    p = bow("render", "--f0", f0, "--fb", beta * physics.omega(f0), "--vb", vb, "--duration", 1.0, d / "t.wav")
    assert p.returncode == 0, p.stderr
    return d, (f0, beta, vb)


def test_fit_writes_a_score_that_plays_the_target(held_target, browser):
    d, (f0, beta, vb) = held_target
    p = bow("fit", "t.wav", "--out", "fitted.toml", "--starts", 2, "--report", "fit.html", cwd=d)
    assert p.returncode == 0, p.stderr
    # the page, in a real browser: the target and the fitted note to listen to (1 s each), harmonics and the bow plane
    info = open_report(browser, d / "fit.html")
    check_page(info, [1.0, 1.0], plots=2)
    assert "twice the best loss" in info["plots"][1]["caption"] and "F_B / w" in info["text"]
    text = (d / "fitted.toml").read_text()
    voice = tomllib.loads(text)["voice"][0]
    # the sound is matched: the fitted note as render plays it, within the instrument's targets of the target
    line = next(ln for ln in text.splitlines() if ln.startswith("# the fitted note against the target"))
    nums = [float(x) for x in __import__("re").findall(r"[-+]?\d+\.\d+", line)]
    assert nums[0] <= 1.0 and abs(nums[1]) <= 1.0, line
    # a note of the same pitch: the fitted f0 sounds where the target does
    sc = note_scene(voice["f0"], voice["fb"] / physics.omega(voice["f0"]), voice["vb"], 1.0, 44100)
    assert 0.01 <= sc.fb / sc.omega <= 2.02 and voice["vb"] > physics.vb_stop(100.0)
    assert "how well the sound determines the bow" in text
    # played as the score's own line says (the model the fit played, in its windows): what the check measured
    play = next(ln for ln in text.splitlines() if ln.startswith("# play it: bowsynth score"))
    args = play.split("bowsynth ", 1)[1].split()
    assert args[:3] == ["score", "--score", "fitted.toml"] and "--model" in args and "--windows" in args, play
    s = bow(*args, cwd=d)
    assert s.returncode == 0, s.stderr
    x, rate = sf.read(d / "fitted.wav")
    y, _ = sf.read(d / "t.wav")
    from bowsynth.metrics import cents, f0_estimate

    n = int(0.8 * rate)
    assert abs(cents(f0_estimate(x[:n], rate), f0_estimate(y[:n], rate))) < 1.0


def test_not_this_instrument_is_refused_and_nothing_written(tmp_path):
    t = np.arange(44100) / 44100
    sf.write(tmp_path / "chord.wav", 0.4 * np.sin(2 * np.pi * 330 * t) + 0.3 * np.sin(2 * np.pi * 415 * t), 44100)
    (tmp_path / "f.toml").write_text("an earlier fit")
    p = bow("fit", "chord.wav", "--out", "f.toml", "--starts", 1, cwd=tmp_path)
    assert p.returncode == 1
    assert "not a match" in one_line(p) and "nothing written" in p.stderr
    assert (tmp_path / "f.toml").read_text() == "an earlier fit"


def _write(path, x, rate=44100):
    sf.write(path, x, rate)
    return path


@pytest.mark.parametrize("kind, code, words", [
    ("stereo", 2, "channels"), ("short", 2, "at least"), ("clipped", 2, "clips"), ("silent", 1, "silent"),
    ("noise", 1, "no steady pitch"), ("rate", 2, "Hz: fit takes"), ("text", 2, "not an audio file"),
])
def test_bad_targets_one_line(tmp_path, kind, code, words):
    t = np.arange(44100) / 44100
    tone = 0.5 * np.sin(2 * np.pi * 200 * t)
    if kind == "stereo":
        _write(tmp_path / "x.wav", np.stack([tone, tone], axis=1))
    elif kind == "short":
        _write(tmp_path / "x.wav", tone[:4000])
    elif kind == "clipped":
        _write(tmp_path / "x.wav", np.clip(3 * tone, -1, 1))
    elif kind == "silent":
        _write(tmp_path / "x.wav", np.zeros(44100))
    elif kind == "noise":
        _write(tmp_path / "x.wav", 0.3 * np.random.default_rng(1).standard_normal(44100))
    elif kind == "rate":
        _write(tmp_path / "x.wav", tone[:2000], rate=4000)
    else:
        (tmp_path / "x.wav").write_text("not audio")
    p = bow("fit", "x.wav", "--out", "f.toml", cwd=tmp_path)
    assert p.returncode == code, p.stderr
    assert words in one_line(p)
    assert not (tmp_path / "f.toml").exists()


def test_out_is_checked_before_any_work(tmp_path):
    _write(tmp_path / "x.wav", 0.5 * np.sin(2 * np.pi * 200 * np.arange(44100) / 44100))
    p = bow("fit", "x.wav", "--out", "x.wav", cwd=tmp_path)
    assert p.returncode == 2 and "x.wav" in one_line(p)
    assert sf.info(tmp_path / "x.wav").frames == 44100


def test_surrogate_is_the_compiled_note_and_has_a_gradient():
    import torch

    from bowsynth.engines.operator.choose import covering_model
    from bowsynth.fit.search import playable
    from bowsynth.fit.surrogate import Note

    for f0, beta, vb, sounding in ((220.0, 0.4, 0.15, None), (150.0, 1.3, 0.2, 60.0)):
        m = covering_model(note_scene(f0, beta, vb, 0.5, 44100), playable())
        note = Note(m, f0, 44100, 22050, sounding=sounding)
        q = note.play((beta, vb))
        b = torch.tensor([beta, vb], dtype=torch.float64, requires_grad=True)
        qt = note(b)
        assert qt.shape == (22050,)
        assert np.max(np.abs(qt.detach().numpy() - q)) < 1e-4 * np.max(np.abs(q))
        qt[len(q) // 2:].square().mean().backward()
        assert torch.all(torch.isfinite(b.grad)) and torch.any(b.grad != 0)


def test_loss_hears_levels_and_dc_as_nothing():
    import torch

    from bowsynth.fit.loss import SoundLoss

    rate = 44100
    t = np.arange(rate) / rate
    y = np.sin(2 * np.pi * 150 * t) + 0.3 * np.sin(2 * np.pi * 300 * t) + 0.1 * np.sin(2 * np.pi * 450 * t)
    loss = SoundLoss(y, rate)
    same = loss.value(0.01 * y + 0.5)
    assert same < 1e-3
    brighter = loss.value(np.sin(2 * np.pi * 150 * t) + 0.6 * np.sin(2 * np.pi * 300 * t))
    sharper = loss.value(np.sin(2 * np.pi * 150 * 2 ** (10 / 1200) * t))
    assert brighter > 10 * max(same, 1e-4) and sharper > 0.5  # 10 cents is one pitch unit of the loss
    parts = loss.parts(torch.as_tensor(y, dtype=torch.float32))
    assert set(parts) == {"spectral", "onset"}
    assert math.isfinite(float(parts["spectral"]))


def test_curves_follow_a_crescendo_and_play(tmp_path):
    """From a flat start at the crescendo's middle bow, the fitted F_B / w rises as the target's does, the curves
    sound nearer the target than the flat start, and the score they are written as plays."""
    from bowsynth import api
    from bowsynth.fit import curves
    from bowsynth.fit.held import Fit
    from bowsynth.fit.search import Candidate, Scorer, f0_for
    from bowsynth.fit.target import read_target
    from bowsynth.fit.write import write_score
    from bowsynth.io.audio import write_wav
    from bowsynth.scene import Scene

    f0 = 150.0
    w = physics.omega(f0)
    sc = Scene(f0=f0, fb=[(0, 0.1 * w), (1.2, 0.3 * w)], vb=0.2, duration=1.2)
    write_wav(tmp_path / "cresc.wav", api.render(sc))
    t = read_target(tmp_path / "cresc.wav")
    scorer = Scorer(t)
    flat = scorer.score(0.2, 0.2, f0_for(scorer.pitch, 0.2, 0.2))
    start = Fit(Candidate(0.2, 0.2, flat.f0, flat.loss, flat.model), {"beta": (0.2, 0.2), "vb": (0.2, 0.2)}, [], 0, 0.0)
    c = curves.fit_curves(t, start, steps=12)
    assert c.loss < flat.loss
    assert c.beta[-1] > 1.3 * c.beta[1]  # the force rises through the note
    assert c.spread.shape == (len(c.times), 2)
    c.checked = curves.check(c, t, api.render)
    write_score(start, tmp_path / "c.toml", "cresc.wav", t.seconds, curves=c)
    voice = tomllib.loads((tmp_path / "c.toml").read_text())["voice"][0]
    assert len(voice["fb"]) == len(c.times) and voice["fb"][-1][1] > voice["fb"][1][1]
    p = bow("score", "--score", "c.toml", "--mix", "c.wav", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    # frame by frame, timbre and pitch give f0 (which the held start lacks) and the force's rise
    from bowsynth.fit.frames import frame_bows

    times, beta, vb, f0_frames = frame_bows(t)
    assert abs(f0_frames / f0 - 1) < 0.01
    assert np.median(beta[-3:]) > 1.5 * np.median(beta[:3])


def test_an_interrupted_fit_keeps_its_best(held_target):
    """Ctrl-C once the search has a best bow: the fit returns it, marked interrupted, instead of losing it."""
    from bowsynth.fit.held import fit_held
    from bowsynth.fit.target import read_target

    d, _ = held_target

    def progress(stage, done, total):
        if stage == "descent":
            raise KeyboardInterrupt

    f = fit_held(read_target(d / "t.wav"), starts=1, progress=progress)
    assert f.interrupted and f.best is not None and math.isfinite(f.best.loss)
