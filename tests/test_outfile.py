"""Output paths, formats, clean audio and files in: symlinks written through, FIFOs never replaced, read-only files
kept, stdout, WAV/FLAC/OGG with their metadata, DC removed without touching the sound, truncated files refused."""

import json
import os
import shutil
import tempfile
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_main

from bowsynth import Scene, render_fdm
from bowsynth.errors import UsageError
from bowsynth.io.audio import read_wav, remove_dc, write_wav
from bowsynth.io.outfile import atomic_write, resolve

FDM = ["render", "--method", "fdm", "-d", "0.2"]


def _only(tmp_path, *names):
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)  # no temp file left anywhere


def test_symlink_is_written_through(tmp_path, monkeypatch, capsys):
    (tmp_path / "t").mkdir()
    link = tmp_path / "link.wav"
    link.symlink_to(tmp_path / "t" / "real.wav")  # dangling at first: the target is created
    for _ in range(2):  # then replaced through the link
        code, _, err = run_main(FDM + [str(link)], capsys, monkeypatch)
        assert code == 0, err
        assert link.is_symlink() and os.readlink(link) == str(tmp_path / "t" / "real.wav")
        assert read_wav(link).meta["method"] == "fdm"
    _only(tmp_path / "t", "real.wav")
    _only(tmp_path, "link.wav", "t")


def test_fifo_is_written_to_not_replaced(tmp_path, monkeypatch, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = {}

    def reader():
        with open(fifo, "rb") as f:
            got["bytes"] = f.read()

    t = threading.Thread(target=reader)
    t.start()
    code, out, err = run_main(FDM + [str(fifo)], capsys, monkeypatch)
    t.join(30)
    assert code == 0, err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)  # still a FIFO, not a regular file in its place
    (tmp_path / "copy.wav").write_bytes(got["bytes"])
    assert read_wav(tmp_path / "copy.wav").scene == Scene(duration=0.2)
    _only(tmp_path, "pipe", "copy.wav")


def test_read_only_file_is_refused_then_forced_keeping_its_mode(tmp_path, monkeypatch, capsys):
    ro = tmp_path / "ro.wav"
    ro.write_bytes(b"precious")
    ro.chmod(0o444)
    code, _, err = run_main(FDM + [str(ro)], capsys, monkeypatch)  # also as root: the mode bits decide
    assert code == 2 and "read-only" in err and "--force" in err and err.count("\n") == 1
    assert ro.read_bytes() == b"precious"
    code, _, err = run_main(FDM + ["--force", str(ro)], capsys, monkeypatch)
    assert code == 0, err
    assert stat.S_IMODE(ro.stat().st_mode) == 0o444 and read_wav(ro).meta is not None
    _only(tmp_path, "ro.wav")


def test_replaced_file_keeps_its_permissions(tmp_path, monkeypatch, capsys):
    f = tmp_path / "p.wav"
    f.write_bytes(b"x")
    f.chmod(0o640)
    code, _, err = run_main(FDM + [str(f)], capsys, monkeypatch)
    assert code == 0, err
    assert stat.S_IMODE(f.stat().st_mode) == 0o640 and f.read_bytes()[:4] == b"RIFF"


def test_stdout_gets_the_wav_and_messages_go_to_stderr(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    r = subprocess.run([sys.executable, "-m", "bowsynth", *FDM, "-"], capture_output=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout[:4] == b"RIFF" and b"wrote standard output" in r.stderr
    (tmp_path / "s.wav").write_bytes(r.stdout)
    assert read_wav(tmp_path / "s.wav").scene == Scene(duration=0.2)


def test_failed_write_leaves_no_temp_file_and_the_old_file(tmp_path):
    old = tmp_path / "keep.wav"
    old.write_bytes(b"old")

    def boom(tmp):
        open(tmp, "wb").write(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(old, boom)
    assert old.read_bytes() == b"old"
    _only(tmp_path, "keep.wav")


def test_output_paths_checked_before_work(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(UsageError, match="directory"):
        resolve(tmp_path / "d")
    loop = tmp_path / "loop.wav"
    loop.symlink_to(loop)
    with pytest.raises(UsageError, match="cannot be used"):
        resolve(loop)


@pytest.mark.parametrize("name", ["x.mp3", "x.aiff", "x", "x.WAV.txt"])
def test_unknown_formats_are_refused_with_the_list(name, tmp_path, monkeypatch, capsys):
    code, _, err = run_main(FDM + [str(tmp_path / name)], capsys, monkeypatch)
    assert code == 2 and ".wav" in err and ".flac" in err and ".ogg" in err and err.count("\n") == 1
    _only(tmp_path)


@pytest.mark.parametrize("ext,lossy", [(".wav", False), (".flac", False), (".ogg", True), (".FLAC", False)])
def test_formats_keep_their_metadata_and_compare(ext, lossy, tmp_path, monkeypatch, capsys):
    f = tmp_path / f"x{ext}"
    code, _, err = run_main(FDM + ["--fb", "50", str(f)], capsys, monkeypatch)
    assert code == 0, err
    info = read_wav(f)
    assert info.scene == Scene(fb=50, duration=0.2) and info.dc_removed
    assert sf.info(str(f)).format == {".wav": "WAV", ".flac": "FLAC", ".ogg": "OGG"}[ext.lower()]
    code, out, err = run_main(["compare", str(f), "--json"], capsys, monkeypatch)
    assert code == 0, err
    j = json.loads(out)
    nmse = j["metrics"]["file vs FDM"]["nmse"]
    if lossy:
        assert any("lossy" in n for n in j["notes"]) and nmse < 1e-2
    else:
        assert not any("lossy" in n for n in j["notes"]) and nmse < 1e-9  # the FDM against itself, DC handled


@pytest.mark.parametrize("args", [["--preset", "paper-fb100"], ["--preset", "paper-fb1000"], ["--preset", "cello-c2"],
                                  ["--fb", "100", "--signal", "p"], ["--preset", "scratch-g2"]])
def test_written_files_have_no_dc(args, tmp_path, monkeypatch, capsys):
    f = tmp_path / "x.wav"
    code, _, err = run_main(["render", "--method", "fdm", "-d", "0.5", *args, str(f)], capsys, monkeypatch)
    assert code == 0, err
    x = read_wav(f).samples
    assert abs(x.mean()) <= 1e-3 * np.abs(x).max()
    code, _, err = run_main(["render", "--method", "fdm", "-d", "0.5", "--dc", "keep", *args, str(f)], capsys,
                            monkeypatch)
    assert code == 0 and not read_wav(f).dc_removed


def test_score_mix_has_no_dc_and_never_clips(tmp_path, monkeypatch, capsys):
    f = tmp_path / "mix.flac"
    code, _, err = run_main(["score", "--presets", "paper-fb100,paper-fb100,paper-fb10", "--method", "fdm", "-d", "0.3",
                             "--mix", str(f)], capsys, monkeypatch)
    assert code == 0, err
    x, _ = sf.read(str(f))
    assert np.abs(x).max() <= 1.0 and np.abs(x).max() > 0.8 and abs(x.mean()) <= 1e-3 * np.abs(x).max()


def _harmonics_db(x, rate, f0, n=10):
    tail = x[len(x) // 2:]
    spec = np.abs(np.fft.rfft((tail - tail.mean()) * np.hanning(len(tail))))
    freqs = np.fft.rfftfreq(len(tail), 1 / rate)
    out = []
    for h in range(1, n + 1):
        band = (freqs > (h - 0.3) * f0) & (freqs < (h + 0.3) * f0)
        out.append(20 * np.log10(spec[band].max()))
    return np.array(out)


@pytest.mark.parametrize("scene", [Scene(fb=100, duration=2.0), Scene(fb=1000, duration=2.0),
                                   Scene(f0=65.4, fb=65.4, duration=2.0)], ids=["fb100", "fb1000-31Hz", "f0-65"])
def test_dc_removal_leaves_the_harmonics(scene):
    """Measured: the 5 Hz zero-phase high-pass changes no harmonic (all above 20 Hz) by 0.01 dB."""
    from bowsynth.metrics import f0_estimate

    u = render_fdm(scene).u
    f0 = f0_estimate(u, scene.sample_rate)
    assert f0 > 20
    before = _harmonics_db(u, scene.sample_rate, f0)
    after = _harmonics_db(remove_dc(u, scene.sample_rate), scene.sample_rate, f0)
    assert np.max(np.abs(after - before)) < 0.01
    assert abs(u.mean()) > 0.01 * np.abs(u).max()  # there was a DC to remove


def test_gain_fixed_level_and_clipping_refused(tmp_path, monkeypatch, capsys):
    f = tmp_path / "g.wav"
    code, _, err = run_main(FDM + ["--gain", "60", str(f)], capsys, monkeypatch)
    assert code == 0, err
    info = read_wav(f)
    assert info.gain == pytest.approx(1000.0)
    code, _, err = run_main(FDM + ["--gain", "200", str(f)], capsys, monkeypatch)
    assert code == 2 and "would clip" in err and "--gain" in err and err.count("\n") == 1
    assert read_wav(f).gain == pytest.approx(1000.0)  # the file from before is untouched


def _wav(tmp_path, name="w.wav", d=0.2):
    f = tmp_path / name
    write_wav(f, render_fdm(Scene(duration=d)))
    return f


@pytest.mark.parametrize("keep", [0.999, 0.75, 0.5, 0.1])
def test_truncated_wav_is_refused(keep, tmp_path, monkeypatch, capsys):
    f = _wav(tmp_path)
    data = f.read_bytes()
    cut = tmp_path / "cut.wav"
    cut.write_bytes(data[:int(len(data) * keep)])
    with pytest.raises(UsageError, match="truncated"):
        read_wav(cut)
    code, out, err = run_main(["compare", str(cut)], capsys, monkeypatch)
    assert code == 2 and "truncated" in err and "present" in err and err.count("\n") == 1 and not out


def test_truncated_foreign_wav_is_refused_too(tmp_path):
    f = tmp_path / "plain.wav"
    sf.write(str(f), np.zeros(1000), 44100, subtype="PCM_16")
    f.write_bytes(f.read_bytes()[:-500])
    with pytest.raises(UsageError, match="truncated"):
        read_wav(f)


def test_metadata_duration_that_disagrees_is_refused(tmp_path, monkeypatch, capsys):
    f = _wav(tmp_path)
    data = f.read_bytes()
    edited = tmp_path / "edited.wav"
    edited.write_bytes(data.replace(b'"duration":0.2', b'"duration":0.4'))
    code, _, err = run_main(["compare", str(edited)], capsys, monkeypatch)
    assert code == 2 and "frames missing" in err and err.count("\n") == 1


def test_truncated_flac_is_caught_by_its_metadata(tmp_path):
    f = tmp_path / "x.flac"
    write_wav(f, render_fdm(Scene(duration=0.5)))
    cut = tmp_path / "cut.flac"
    cut.write_bytes(f.read_bytes()[:len(f.read_bytes()) // 2])
    with pytest.raises(UsageError, match="missing|not a readable"):
        read_wav(cut)


def test_edited_header_data_size_is_refused(tmp_path):
    f = _wav(tmp_path)
    data = bytearray(f.read_bytes())
    i = data.find(b"data")
    n = int.from_bytes(data[i + 4:i + 8], "little")
    data[i + 4:i + 8] = (n + 4000).to_bytes(4, "little")  # the header promises 1000 frames more than are there
    (tmp_path / "e.wav").write_bytes(bytes(data))
    with pytest.raises(UsageError, match="truncated"):
        read_wav(tmp_path / "e.wav")


@pytest.mark.parametrize("n", [92_604, 48_505, 4_410, 441])
def test_dc_removal_is_the_ideal_zero_phase_filter(n):
    """The compiled recursive filter, forward and backward, against the ideal zero-phase response (f/fc)^4 /
    (1 + (f/fc)^4) applied in the frequency domain to the signal padded by 4 s of odd reflection (its circular wrap
    rings out to e^-88): the same samples to 2e-5 of the peak (-94 dB; measured 0.3-1.0e-5: the bilinear warp and
    what is left of each pass's start-up after the 0.5 s padding)."""
    from bowsynth.io.audio import DC_HZ, remove_dc

    rng = np.random.default_rng(n)
    x = 0.05 + np.cumsum(rng.standard_normal(n)) * 1e-3 + np.sin(np.arange(n) * 0.014)
    pad = 4 * 44100
    padded = np.pad(x, pad, mode="reflect", reflect_type="odd")
    f4 = (np.fft.rfftfreq(padded.size, 1 / 44100) / DC_HZ) ** 4
    y = np.fft.irfft(np.fft.rfft(padded) * (f4 / (1 + f4)), n=padded.size)[pad:pad + n]
    assert np.max(np.abs(remove_dc(x, 44100) - (y - y.mean()))) < 2e-5 * np.abs(x).max()


@pytest.mark.parametrize("n,pad", [(10, 9), (10, 1), (1000, 0), (50_000, 22_050)])
def test_odd_reflection_is_numpys(n, pad):
    from bowsynth.io.audio import PEAK, gain_for, odd_reflection

    x = np.random.default_rng(n).standard_normal(n)
    assert np.array_equal(odd_reflection(x, pad), np.pad(x, pad, mode="reflect", reflect_type="odd"))
    assert gain_for(x, None) == gain_for(-x, None) == PEAK / np.abs(x).max()


def test_an_output_that_is_an_input_is_refused_and_the_input_kept(tmp_path, capsys, monkeypatch):
    """compare's --report / --plot on the file it reads (its path, a symlink or a hard link to it), a score's mix on
    the score file, and a mix inside its own stems' directory: one line, exit 2, the input untouched and nothing
    written."""
    from conftest import run_main

    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.3", "in.wav"], capsys, monkeypatch)
    assert code == 0, err
    before = (tmp_path / "in.wav").read_bytes()
    (tmp_path / "link.html").symlink_to(tmp_path / "in.wav")
    os.link(tmp_path / "in.wav", tmp_path / "hard.png")
    for args in (["--report", "in.wav"], ["--report", "link.html"], ["--plot", "hard.png"]):
        code, out, err = run_main(["compare", "in.wav", *args], capsys, monkeypatch)
        assert code == 2 and "is the input" in err and len(err.strip().splitlines()) == 1, err
    assert (tmp_path / "in.wav").read_bytes() == before
    (tmp_path / "piece.toml").write_text('[[voice]]\nname = "a"\nduration = 0.1\nfb = 100.0\n')
    score = (tmp_path / "piece.toml").read_bytes()
    code, out, err = run_main(["score", "--score", "piece.toml", "--mix", "piece.toml", "--force"], capsys,
                              monkeypatch)
    assert code == 2 and "is the input" in err and (tmp_path / "piece.toml").read_bytes() == score
    (tmp_path / "st").mkdir()
    for mix, stems in (("st/v.wav", "st"), ("m.wav", "m.wav")):
        code, out, err = run_main(["score", "--score", "piece.toml", "--mix", mix, "--stems", stems], capsys,
                                  monkeypatch)
        assert code == 2 and "collide" in err, err
    assert not (tmp_path / "m.wav").exists() and list((tmp_path / "st").iterdir()) == []


def _as_user(tmp_path):
    """The command prefix that runs a process without write permission on a mode-555 folder: as nobody where this
    runs as root (root writes anywhere), else as the user itself."""
    if os.geteuid() != 0:
        return []
    if not shutil.which("setpriv"):
        pytest.skip("running as root without setpriv: no unprivileged user to run as")
    # nobody must reach the folder by its path: pytest's own folders are root's alone
    for d in [tmp_path, *tmp_path.parents]:
        if d == Path(tempfile.gettempdir()):
            break
        d.chmod(d.stat().st_mode | 0o711)
    tmp_path.chmod(0o777)
    return ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]


@pytest.mark.parametrize("args", [
    ["score", "--score", "s.toml", "--mix", "m.wav", "--stems", "ro/stems"],
    ["train", "--fb", "100", "--steps", "2", "--out", "ro/m.safetensors"],
    ["dataset", "spec.toml", "--out", "ro/corpus"],
], ids=["score-stems", "train-out", "dataset-out"])
def test_a_folder_without_write_permission_is_one_line(args, tmp_path):
    """A real process run by a user who may not write into ro/: one line naming the path, exit 1, nothing written
    anywhere (the mix waits for its stems)."""
    prefix = _as_user(tmp_path)
    (tmp_path / "ro").mkdir(mode=0o555)
    (tmp_path / "ro").chmod(0o555)
    (tmp_path / "s.toml").write_text("[[voice]]\nf0 = 220\nfb = 300\nvb = 0.17\nduration = 0.3\n")
    (tmp_path / "spec.toml").write_text("count = 2\nseed = 1\n")
    (tmp_path / "cache").mkdir(mode=0o777)
    (tmp_path / "cache").chmod(0o777)
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), "HOME": str(tmp_path)}
    before = sorted(p.name for p in tmp_path.iterdir())
    p = subprocess.run(prefix + [sys.executable, "-m", "bowsynth", *args], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=300)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 1 and len(lines) == 1, p.stderr
    assert lines[0].startswith("error: ro/") and "Permission denied" in lines[0] and "internal" not in lines[0]
    assert list((tmp_path / "ro").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == before
