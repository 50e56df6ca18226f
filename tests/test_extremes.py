"""Extreme finite numbers on every numeric flag of every command: one line and exit 2 before any work, or a correct
result; never an internal error, a traceback, a non-finite sample or a run of minutes."""

import math

import numpy as np
import pytest
import soundfile as sf
from conftest import run_main
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

EXTREME_FLOATS = [1e-300, -1e-300, 5e-324, 1e308, -1e308, 1.7976931348623157e308, -0.0, 0.0, 1.0, -1.0, 0.5, 1e9,
                  1e-9, 15000.0, 18000.0, 22049.0, 22050.0, 22051.0, 3600.0, 3600.0001, 1e6]
EXTREME_INTS = [0, -1, 1, 2, 8000, 44100, 384000, 384001, 1024, 100_000, 10**9, 2**31, 2**63, 10**18, 10**30]
FLOATS = st.one_of(st.sampled_from(EXTREME_FLOATS), st.floats(allow_nan=False, allow_infinity=False))
INTS = st.one_of(st.sampled_from(EXTREME_INTS), st.integers(-10, 10**6))
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _one_line_or_ok(code, err):
    assert "Traceback" not in err and "internal error" not in err, err
    lines = [ln for ln in err.strip().splitlines() if ln and not ln.startswith("warning:")]
    if code != 0:
        assert code in (1, 2) and len(lines) == 1, err


def _check_written(path):
    x, _ = sf.read(str(path))
    assert np.all(np.isfinite(x))
    peak = np.abs(x).max()
    assert peak <= 1.0 and abs(x.mean()) <= 1e-3 * peak + 1e-30


RENDER_FLOATS = ["--f0", "--fb", "--vb", "--a", "--q0", "--p0", "--duration", "--gain"]


@pytest.fixture
def no_shipped_models(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("bowsynth.engines.operator.choose.SHIPPED_DIR", tmp_path / "none")


@SETTINGS
@given(flag=st.sampled_from(RENDER_FLOATS), value=FLOATS, method=st.sampled_from(["fdm", "operator"]))
# a subnormal force: the note's growth time can overflow to inf where the operator asks when it should speak
@example(flag="--fb", value=2.225073858507203e-309, method="operator")
def test_render_float_flags(flag, value, method, tmp_path, monkeypatch, capsys):
    out = tmp_path / "r.wav"
    out.unlink(missing_ok=True)
    dur = [] if flag == "--duration" else ["-d", "0.01"]
    code, _, err = run_main(["render", "--method", method, *dur, flag, repr(value), str(out)], capsys, monkeypatch)
    _one_line_or_ok(code, err)
    if code == 0:
        _check_written(out)
    else:
        assert not out.exists()


@SETTINGS
@given(flag=st.sampled_from(["--sr", "--oversample"]), value=INTS)
def test_render_int_flags(flag, value, tmp_path, monkeypatch, capsys):
    out = tmp_path / "r.wav"
    out.unlink(missing_ok=True)
    code, _, err = run_main(["render", "--method", "fdm", "-d", "0.001", flag, str(value), str(out)], capsys,
                            monkeypatch)
    _one_line_or_ok(code, err)
    if code == 0:
        _check_written(out)


def test_huge_oversample_is_refused_with_the_estimate(tmp_path, monkeypatch, capsys):
    code, _, err = run_main(["render", "--method", "fdm", "--oversample", "100000", str(tmp_path / "o.wav")], capsys,
                            monkeypatch)
    assert code == 2 and "would take about" in err and "--force" in err and err.count("\n") == 1


@pytest.mark.parametrize("f0", [14500.0, 15000.0, 18000.0, 22000.0, 22049.0])
def test_pitches_near_nyquist_render_finite(f0, tmp_path, monkeypatch, capsys):
    """The audio-rate scheme is unstable above sample_rate / pi (f0 14 kHz at 44.1 kHz): the FDM oversamples."""
    from bowsynth.engines.fdm import OversampleWarning

    out = tmp_path / "n.wav"
    with pytest.warns(OversampleWarning, match="stability bound"):
        code, _, err = run_main(["render", "--method", "fdm", "-d", "0.05", "--f0", str(f0), str(out)], capsys,
                                monkeypatch)
    assert code == 0, err
    _check_written(out)


@pytest.mark.parametrize("args,needle", [
    (["--fb", "1e308"], "fb must be within"), (["--vb", "1e308"], "vb must be within"),
    (["--a", "1e308"], "a must be within"), (["--q0", "-1e308"], "q0 must be within"),
    (["--f0", "1e-300"], "f0 must be >="), (["--duration", "1e308"], "duration must be <="),
    (["--gain", "1e308"], "--gain must be"), (["-d", "3600", "--sr", "384000"], "GB of memory"),
])
def test_known_extremes_refused_before_work(args, needle, tmp_path, monkeypatch, capsys):
    out = tmp_path / "e.wav"
    code, _, err = run_main(["render", "--method", "fdm", *args, str(out)], capsys, monkeypatch)
    assert code == 2 and needle in err and err.count("\n") == 1
    assert not out.exists()


def test_tiny_bow_force_renders_silence_not_nan(tmp_path, monkeypatch, capsys):
    out = tmp_path / "t.wav"
    with pytest.warns(UserWarning, match="silence"):
        code, _, err = run_main(["render", "--method", "fdm", "-d", "0.05", "--fb", "1e-300", str(out)], capsys,
                                monkeypatch)
    assert code == 0, err
    _check_written(out)


TRAIN_FLOATS = ["--f0", "--fb", "--vb", "--a", "--q0", "--p0", "--minutes", "--lbfgs", "--window-ms",
                "--checkpoint-every"]
TRAIN_INTS = ["--steps", "--seed", "--width", "--depth", "--n-data", "--batch"]


@pytest.fixture
def fake_train(monkeypatch):
    """Stand in for the trainer (minutes of work per example): the real config validation runs, then the config
    must be a budget that ends with settings the trainer can use; then stop."""
    from bowsynth.errors import BowsynthError

    seen = {}

    class Stop(BowsynthError):
        exit_code = 1

    def train(scene, config=None, **kw):
        config.validate()
        assert config.minutes is None or (math.isfinite(config.minutes) and 0 < config.minutes <= 7 * 24 * 60)
        assert config.steps is None or 1 <= config.steps <= 10**9
        assert config.minutes or config.steps
        assert config.net.width >= 1 and config.net.depth >= 1 and 0 <= config.seed < 2**64
        assert config.window is None or math.isfinite(config.window) and config.window > 0
        assert math.isfinite(config.checkpoint_seconds) and 1 <= config.batch_states <= 10**6
        seen["called"] = True
        seen["box"] = kw.get("box")
        raise Stop("stopped by the test")

    monkeypatch.setattr("bowsynth.api.train", train)
    return seen


@SETTINGS
@given(flag=st.sampled_from(TRAIN_FLOATS + TRAIN_INTS), fval=FLOATS, ival=INTS)
def test_train_flags(flag, fval, ival, fake_train, tmp_path, monkeypatch, capsys):
    value = str(ival) if flag in TRAIN_INTS else repr(fval)
    code, _, err = run_main(["train", "--out", str(tmp_path / "m.safetensors"), flag, value], capsys, monkeypatch)
    _one_line_or_ok(code, err)
    assert code == 2 or "stopped by the test" in err


@SETTINGS
@given(flag=st.sampled_from(["--fb", "--vb"]), lo=FLOATS, hi=FLOATS)
def test_train_range_flags(flag, lo, hi, fake_train, tmp_path, monkeypatch, capsys):
    """`train --fb LO:HI` / `--vb LO:HI` with extreme numbers: one line and exit 2, or a box that is finite, not
    inverted and inside the scene's bounds reaches the trainer."""
    fake_train.clear()
    code, _, err = run_main(["train", "--out", str(tmp_path / "m.safetensors"), flag, f"{lo!r}:{hi!r}"], capsys,
                            monkeypatch)
    _one_line_or_ok(code, err)
    assert code == 2 or "stopped by the test" in err
    box = fake_train.get("box")
    if box is not None:
        assert all(math.isfinite(v) for v in (box.beta_lo, box.beta_hi, box.vb_lo, box.vb_hi))
        assert 0 <= box.beta_lo <= box.beta_hi and box.vb_lo <= box.vb_hi


@SETTINGS
@given(flag=st.sampled_from(["--fb", "--vb"]), v0=FLOATS, v1=FLOATS, t1=FLOATS)
def test_render_curve_flags(flag, v0, v1, t1, no_shipped_models, tmp_path, monkeypatch, capsys):
    """Curves with extreme values and times on render: one line and exit 2, or a finite, clean file."""
    out = tmp_path / "x.wav"
    out.unlink(missing_ok=True)  # hypothesis runs every example in the same directory
    code, _, err = run_main(["render", "--method", "fdm", "-d", "0.05", flag, f"{v0!r}@0,{v1!r}@{t1!r}", str(out)],
                            capsys, monkeypatch)
    _one_line_or_ok(code, err)
    if code == 0:
        _check_written(out)
    else:
        assert not out.exists()


@pytest.mark.parametrize("minutes", ["inf", "1e308", "1e300", "-0.0", "1e-300"])
def test_training_budget_that_never_ends_is_refused(minutes, fake_train, tmp_path, monkeypatch, capsys):
    code, _, err = run_main(["train", "--minutes", minutes], capsys, monkeypatch)
    if minutes == "1e-300":  # a tiny budget ends at once: accepted
        assert "stopped by the test" in err
        return
    assert code == 2 and "--minutes" in err and not fake_train


@SETTINGS
@given(flag=st.sampled_from(["--f0", "--fb", "--vb", "--a", "--q0", "--p0"]), value=FLOATS)
def test_compare_scene_flags(flag, value, tmp_path, monkeypatch, capsys):
    plain = tmp_path / "plain.wav"
    if not plain.exists():
        sf.write(str(plain), np.sin(np.arange(441) * 0.1), 44100, subtype="FLOAT")
    code, out, err = run_main(["compare", str(plain), "--json", flag, repr(value)], capsys, monkeypatch)
    _one_line_or_ok(code, err)


@SETTINGS
@given(flag=st.sampled_from(["--duration", "--gain"]), value=FLOATS)
def test_score_float_flags(flag, value, tmp_path, monkeypatch, capsys):
    out = tmp_path / "mix.wav"
    out.unlink(missing_ok=True)
    dur = [] if flag == "--duration" else ["-d", "0.01"]
    code, _, err = run_main(["score", "--presets", "paper-fb100,paper-fb10", "--method", "fdm", "--mix", *dur, flag,
                             repr(value), str(out)], capsys, monkeypatch)
    _one_line_or_ok(code, err)
    if code == 0:
        _check_written(out)


def test_thousand_voice_mix_fits_its_metadata(tmp_path, monkeypatch, capsys):
    score = tmp_path / "big.toml"
    score.write_text("[defaults]\nduration = 0.005\n" + "".join(
        f'[[voice]]\nname = "a-rather-long-voice-name-{i}"\nfb = {50 + i % 50}\n' for i in range(1000)))
    out = tmp_path / "mix.wav"
    code, _, err = run_main(["score", "--score", str(score), "--method", "fdm", "--mix", "-q", str(out)], capsys,
                            monkeypatch)
    assert code == 0, err
    import json

    meta = json.loads(sf.SoundFile(str(out)).comment)
    assert meta["voices"] == 1000 and meta["names_truncated"] and 0 < len(meta["names"]) < 1000
    _check_written(out)
