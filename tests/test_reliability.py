"""Bad input, safe files, nothing lost: one clear line, the right exit code, no traceback, files kept."""

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import run_main
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bowsynth import Scene, SceneError

BOW = [sys.executable, "-m", "bowsynth"]


BAD = [
    (["render", "--method", "fdm", "--fb", "nan", "x.wav"], 2, "fb must be finite"),
    (["render", "--method", "fdm", "--fb", "-5", "x.wav"], 2, "fb must be >= 0"),
    (["render", "--method", "fdm", "--f0", "30000", "x.wav"], 2, "Nyquist"),
    (["render", "--method", "fdm", "--sr", "1000", "x.wav"], 2, "sample_rate must be in"),
    (["render", "--method", "fdm", "--duration", "0", "x.wav"], 2, "duration must be > 0"),
    (["render", "--method", "fdm", "--preset", "nope", "x.wav"], 2, "unknown preset"),
    (["render", "--method", "fdm", "--fb", "abc", "x.wav"], 2, "--fb"),
    (["render", "--method", "banana", "x.wav"], 2, "--method must be"),
    (["render", "--method", "fdm", "missing_dir/x.wav"], 2, "does not exist"),
    (["render", "--model", "nomodel.safetensors", "x.wav"], 1, "not found"),
    (["render", "--model", "garbage.safetensors", "x.wav"], 1, "not a readable model file"),
    (["compare", "nofile.wav"], 2, "not found"),
    (["compare", "garbage.wav"], 2, "not a readable audio file"),
    (["compare", "plain.wav"], 2, "no bowsynth metadata"),
    (["train", "--fb", "100", "--steps", "0"], 2, "--steps must be >= 1"),
    (["train", "--fb", "100", "--optimizer", "sgd", "--steps", "1", "--out", "m.safetensors"], 2, "--optimizer"),
    (["train", "--fb", "100", "--resume", "--out", "m.safetensors"], 2, "no checkpoint"),
    (["score", "outdir"], 2, "exactly one of"),
    (["score", "--score", "bad.toml", "outdir"], 2, "not valid TOML"),
    (["bench", "gpu"], 2, "fdm, equal, map or all"),
    (["bench", "--anchors", "no_such_dir"], 2, "not a directory"),
    (["score", "--presets", "paper-fb100", "--fallback", "maybe", "outdir"], 2, "--fallback must be"),
]


@pytest.mark.parametrize("args,code,needle", BAD, ids=[" ".join(b[0][:3]) for b in BAD])
def test_bad_input_one_line(args, code, needle, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("bowsynth.engines.operator.choose.SHIPPED_DIR", tmp_path / "none")
    (tmp_path / "garbage.safetensors").write_bytes(b"\x00garbage" * 10)
    (tmp_path / "garbage.wav").write_bytes(b"RIFF0000WAVEjunk" * 4)
    (tmp_path / "bad.toml").write_text("[[voice]\nfb = ")
    import soundfile as sf

    sf.write(tmp_path / "plain.wav", np.zeros(100), 44100)
    got, out, err = run_main(args, capsys, monkeypatch)
    assert got == code, err
    assert needle in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "x.wav").exists()


def test_unwritable_output_directory(tmp_path, monkeypatch, capsys):
    if os.geteuid() == 0:
        # root ignores permissions: use a path under a regular file instead
        (tmp_path / "f").write_text("")
        code, _, err = run_main(["render", "--method", "fdm", str(tmp_path / "f" / "x.wav")], capsys, monkeypatch)
        assert code == 2 and "does not exist" in err
        return
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    code, _, err = run_main(["render", "--method", "fdm", str(ro / "x.wav")], capsys, monkeypatch)
    assert code == 2 and "not writable" in err


def test_existing_wav_is_replaced_atomically_and_kept_on_failure(tmp_path, monkeypatch, capsys):
    wav = tmp_path / "keep.wav"
    wav.write_bytes(b"precious")
    # a failing render (bad scene) must leave the existing file untouched
    code, _, _ = run_main(["render", "--method", "fdm", "--fb", "-1", str(wav)], capsys, monkeypatch)
    assert code == 2 and wav.read_bytes() == b"precious"
    code, _, _ = run_main(["render", "--method", "fdm", "-d", "0.05", str(wav)], capsys, monkeypatch)
    assert code == 0 and wav.read_bytes()[:4] == b"RIFF"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.wav"]


def test_no_nan_reaches_a_wav(tmp_path):
    from bowsynth.io.audio import write_wav
    from bowsynth.render import Played, Render

    sc = Scene(duration=0.01)
    r = Render(sc, np.zeros(441), np.full(441, np.nan), np.zeros(441), method=Played("fdm"))
    with pytest.raises(ValueError, match="non-finite"):
        write_wav(tmp_path / "n.wav", r)
    assert not list(tmp_path.iterdir())


@settings(max_examples=150, deadline=None)
@given(f0=st.floats(allow_nan=True, allow_infinity=True), fb=st.floats(allow_nan=True, allow_infinity=True),
       a=st.floats(allow_nan=True, allow_infinity=True), duration=st.floats(allow_nan=True, allow_infinity=True),
       rate=st.integers(-10, 10**6))
def test_scene_accepts_exactly_the_valid_values(f0, fb, a, duration, rate):
    valid = (all(math.isfinite(v) for v in (f0, fb, a, duration)) and f0 >= 1 and 0 <= fb <= 1e9 and 1e-9 <= a <= 1e9
             and 0 < duration <= 3600 and 8000 <= rate <= 384000 and f0 < rate / 2 and duration * rate >= 2)
    try:
        s = Scene(f0=f0, fb=fb, a=a, duration=duration, sample_rate=rate)
    except SceneError as e:
        assert not valid, f"rejected a valid scene: {e}"
        assert str(e).split()[0] in {"f0", "fb", "a", "duration", "sample_rate"}
    else:
        assert valid and s.sample_rate == rate


ARG = st.sampled_from(["--fb", "--f0", "--vb", "--a", "--duration", "--sr", "--q0", "--p0", "--preset", "--method",
                       "--signal", "--oversample", "--fallback", "--bogus", "-d", "--quiet"])
VAL = st.one_of(st.sampled_from(["nan", "inf", "-inf", "-1", "0", "1e400", "abc", "", "paper-fb10", "fdm", "u", "p",
                                 "none", "1e-9", "99999999"]),
                st.floats(allow_nan=False, width=32).map(str), st.text(max_size=5))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(args=st.lists(st.tuples(ARG, VAL), max_size=4))
def test_cli_never_tracebacks(args, tmp_path, monkeypatch, capsys):
    flat = ["render", "--method", "fdm", "-d", "0.01"] + [x for pair in args for x in pair] + [str(tmp_path / "h.wav")]
    code, out, err = run_main(flat, capsys, monkeypatch)
    assert "Traceback" not in err and "internal error" not in err, err
    if code != 0:
        assert code in (1, 2) and err.strip().count("\n") <= 1 + err.count("warning:")


@pytest.mark.parametrize("args", [["--quiet", "\x00"], ["--preset", "paper\x00fb10"], ["--f0", "\x00"]])
def test_a_nul_byte_in_an_argument_is_one_usage_line(args, tmp_path, capsys, monkeypatch):
    """Hypothesis found `render --quiet NUL out.wav` (NUL taken as the output) ending in typer's os.stat ValueError:
    main() called in-process can be given what a process's argv cannot hold."""
    code, out, err = run_main(["render", "--method", "fdm", "-d", "0.01", *args, str(tmp_path / "h.wav")], capsys,
                              monkeypatch)
    assert code == 2 and err.strip() == "error: an argument contains a NUL byte (\\x00): no option value or file name can"
    assert not (tmp_path / "h.wav").exists()


def test_kill_training_then_resume(tmp_path):
    """SIGKILL a training run after its first checkpoint; --resume continues from it to a finished model."""
    out = tmp_path / "k.safetensors"
    ckpt = tmp_path / "k.ckpt.safetensors"
    common = ["train", "--fb", "100", "--width", "16", "--depth", "2", "--n-data", "64", "--out", str(out), "--quiet",
              "--checkpoint-every", "0.5"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(BOW + common + ["--steps", "1000000", "--minutes", "10"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.time()
    while not ckpt.exists() and time.time() - t0 < 120:
        time.sleep(0.2)
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert ckpt.exists() and not out.exists()
    import json

    from safetensors import safe_open

    with safe_open(str(ckpt), framework="pt") as f:
        step = json.loads(f.metadata()["bowsynth_checkpoint"])["step"]
    assert step > 0
    kept = ckpt.read_bytes()
    # the same command again, without --resume: the interrupted run is not thrown away (it may hold 40 minutes)
    again = subprocess.run(BOW + common + ["--steps", str(step + 20)], capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and again.stderr.count("\n") == 1, again.stderr
    assert "unfinished run" in again.stderr and "--resume" in again.stderr and "--force" in again.stderr
    assert ckpt.read_bytes() == kept and not out.exists()
    r = subprocess.run(BOW + common + ["--steps", str(step + 20), "--resume"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert out.exists() and not ckpt.exists()
    from bowsynth.engines.operator.modelfile import load_model

    assert load_model(out).meta.training["steps_done"] == step + 20


def test_a_validation_that_fails_keeps_the_trained_network_for_resume(tmp_path, monkeypatch, capsys):
    """An error after the budget is spent (a validation that crashed after 40 minutes of training) keeps
    the trained network in the checkpoint and says so in its one line; --resume then validates without training."""
    import bowsynth.training
    from conftest import run_main

    out, ckpt = tmp_path / "v.safetensors", tmp_path / "v.ckpt.safetensors"
    args = ["train", "--fb", "100", "--width", "16", "--depth", "2", "--n-data", "64", "--steps", "30", "--out",
            str(out), "--quiet"]
    real = bowsynth.training.validate

    def broken(*a, **k):
        raise AttributeError("'OperatorModel' object has no attribute 'key'")

    monkeypatch.setattr(bowsynth.training, "validate", broken)
    code, _, err = run_main(args, capsys, monkeypatch)
    assert code == 1 and err.count("\n") == 1 and err.startswith("internal error: AttributeError"), err
    assert f"kept in {ckpt}" in err and "--resume" in err and ckpt.exists() and not out.exists()
    monkeypatch.setattr(bowsynth.training, "validate", real)
    code, _, err = run_main(args + ["--resume"], capsys, monkeypatch)
    assert code == 0, err
    from bowsynth.engines.operator.modelfile import load_model

    m = load_model(out)
    assert m.meta.training["steps_done"] == 30 and m.meta.validation["seconds"] == 1.0 and not ckpt.exists()


def test_ctrl_c_keeps_a_checkpoint(tmp_path):
    out = tmp_path / "c.safetensors"
    ckpt = tmp_path / "c.ckpt.safetensors"
    proc = subprocess.Popen(BOW + ["train", "--fb", "100", "--width", "16", "--depth", "2", "--n-data", "64", "--out",
                                   str(out), "--quiet", "--steps", "1000000", "--minutes", "10",
                                   "--checkpoint-every", "0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.time()
    while not ckpt.exists() and time.time() - t0 < 180:  # training proper has begun (data preparation is done)
        time.sleep(0.2)
    ckpt.unlink()  # the checkpoint asserted below is the one Ctrl-C writes
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "checkpoint saved" in err and "--resume" in err and err.count("\n") == 1, err
    assert (tmp_path / "c.ckpt.safetensors").exists() and not out.exists()


def test_written_files_get_normal_permissions(tmp_path, monkeypatch, capsys):
    wav = tmp_path / "perm.wav"
    code, _, _ = run_main(["render", "--method", "fdm", "-d", "0.02", str(wav)], capsys, monkeypatch)
    assert code == 0
    mask = os.umask(0o022)
    os.umask(mask)
    assert wav.stat().st_mode & 0o777 == 0o666 & ~mask


def test_wheel_carries_presets_and_shipped_models(tmp_path):
    """A non-editable install must find the presets, the shipped models and their recipes (package data) and the
    compiled core: the wheel carries all of them."""
    import subprocess
    import sys
    import zipfile

    pytest.importorskip("scikit_build_core")  # the test extra installs it
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                        str(tmp_path), str(root)], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    names = zipfile.ZipFile(next(tmp_path.glob("bowsynth-*.whl"))).namelist()
    for p in [*(root / "presets").glob("*.toml"), *(root / "models").glob("*.safetensors"),
              *(root / "models").glob("*.toml")]:
        assert f"bowsynth/{p.parent.name}/{p.name}" in names
    assert any(n.startswith("bowsynth/_core.") and n.endswith(".so") for n in names), names
    # installed from the wheel and run from elsewhere (no site: the checkout's editable finder stays out), the
    # program reads the presets and the models the wheel carries, not the checkout's
    import sysconfig

    target = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target),
                        str(next(tmp_path.glob("bowsynth-*.whl")))], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    env = {**os.environ, "PYTHONPATH": f"{target}{os.pathsep}{sysconfig.get_paths()['purelib']}",
           "XDG_CACHE_HOME": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-S", "-m", "bowsynth", "render", "--preset", "paper-fb100", "-d", "0.2",
                        str(tmp_path / "w.wav")], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"({target / 'bowsynth' / 'models' / 'paper-fb100.safetensors'})" in r.stdout + r.stderr, r.stdout


def test_a_signal_during_a_checkpoint_write_waits_for_it():
    """Ctrl-C arriving while a checkpoint is written is delivered after the write: the file is whole."""
    from bowsynth.errors import held

    done = []
    with pytest.raises(KeyboardInterrupt):
        with held():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            done.append("written")
    assert done == ["written"]
