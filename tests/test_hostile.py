"""Hostile but realistic input: one line, the right exit code, nothing written."""

import os
import stat
import subprocess
import sys

import numpy as np
import pytest
import soundfile as sf
from conftest import run_main


def _one_line(err):
    lines = [x for x in err.strip().splitlines() if x.strip()]
    return len(lines) == 1 and "internal error" not in err and "Traceback" not in err


@pytest.fixture
def files(tmp_path):
    sf.write(tmp_path / "nometa.wav", (0.1 * np.sin(2 * np.pi * 100 * np.arange(4410) / 44100)).astype("float32"),
             44100)
    sf.write(tmp_path / "e1.wav", np.zeros(0, "float32"), 44100)
    sf.write(tmp_path / "e2.wav", np.zeros(0, "float32"), 44100)
    (tmp_path / "deep.toml").write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    return tmp_path


CASES = {
    "window shorter than a sample": (["train", "--fb", "100", "--window-ms", "1e-320", "--steps", "1"], 2,
                                     "holds no sample"),
    "silent reference": (["compare", "{d}/nometa.wav", "--vb", "-0.0"], 2, "is silent"),
    "empty files": (["compare", "{d}/e1.wav", "{d}/e2.wav"], 2, "holds no samples"),
    "deep TOML score": (["score", "--score", "{d}/deep.toml", "--mix", "{d}/m.wav"], 2, "too deeply"),
    "preset given as a path": (["render", "--preset", "../presets/paper-fb100", "{d}/x.wav"], 2, "unknown preset"),
    "300-character name": (["render", "--fb", "100", "-d", "0.1", "{d}/" + "a" * 300 + ".wav"], 2, "too long"),
    "non-UTF-8 name": (["render", "--fb", "100", "-d", "0.1", "{d}/x\udcff.wav"], 2, "not valid UTF-8"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_hostile_input_gets_one_line(case, files, capsys, monkeypatch):
    args, want_code, says = CASES[case]
    monkeypatch.chdir(files)
    code, out, err = run_main([a.replace("{d}", str(files)) for a in args], capsys, monkeypatch)
    assert code == want_code and says in err and _one_line(err), (code, out, err)
    assert not any(p.suffix in (".wav", ".safetensors") and p.name not in ("nometa.wav", "e1.wav", "e2.wav")
                   for p in files.iterdir())


def test_scene_flags_on_a_file_with_its_scene_are_refused(tmp_path, capsys, monkeypatch):
    code, _, _ = run_main(["render", "--method", "fdm", "--fb", "50", "-d", "0.1", str(tmp_path / "p.wav")], capsys,
                          monkeypatch)
    assert code == 0
    code, out, err = run_main(["compare", str(tmp_path / "p.wav"), "--vb", "0.1"], capsys, monkeypatch)
    assert code == 2 and "carries its scene" in err and _one_line(err)


def test_a_bow_too_weak_to_move_the_mass_warns(tmp_path, capsys, monkeypatch):
    with pytest.warns(UserWarning, match="silent"):  # the CLI prints it as one 'warning:' line
        code, out, err = run_main(["render", "--method", "fdm", "--fb", "1e-320", "-d", "0.1",
                                   str(tmp_path / "z.wav")], capsys, monkeypatch)
    assert code == 0


def _reforge(path, edit):
    """Rewrite a WAV's bowsynth comment as an editor would."""
    import json

    with sf.SoundFile(str(path)) as f:
        data, rate, meta = f.read(dtype="float32"), f.samplerate, json.loads(f.comment)
    edit(meta)
    with sf.SoundFile(str(path), "w", samplerate=rate, channels=1, subtype="FLOAT") as f:
        f.comment = json.dumps(meta)
        f.write(data)


@pytest.mark.parametrize("field, value", [("render_seconds", "fast"), ("signal", "x"), ("render_seconds", -1),
                                          ("method", 3), ("signal", None)])
def test_compare_refuses_forged_metadata_fields_in_one_line(tmp_path, capsys, monkeypatch, field, value):
    w = tmp_path / "p.wav"
    assert run_main(["render", "--method", "fdm", "--fb", "50", "-d", "0.1", str(w)], capsys, monkeypatch)[0] == 0
    _reforge(w, lambda m: m.__setitem__(field, value))
    code, out, err = run_main(["compare", str(w), "--reference", "audio"], capsys, monkeypatch)
    assert code == 2 and "damaged bowsynth metadata" in err and _one_line(err), err


@pytest.mark.parametrize("field, value", [("duration", "abc"), ("start", None), ("file", "../../etc/passwd")])
def test_compare_refuses_a_forged_stems_index(tmp_path, capsys, monkeypatch, field, value):
    import json

    (tmp_path / "s.toml").write_text('[[voice]]\nname = "v"\nf0 = 120.0\nbeta = 0.159155\nduration = 0.2\n')
    code, out, err = run_main(["score", "--score", str(tmp_path / "s.toml"), "--method", "fdm", "--mix",
                               str(tmp_path / "m.wav"), "--stems", str(tmp_path / "st")], capsys, monkeypatch)
    assert code == 0, err
    idx = tmp_path / "st" / "notes.json"
    doc = json.loads(idx.read_text())
    doc["notes"][0][field] = value
    idx.write_text(json.dumps(doc))
    code, out, err = run_main(["compare", str(tmp_path / "m.wav"), "--reference", "audio"], capsys, monkeypatch)
    assert code == 2 and "damaged" in err and _one_line(err), err


def test_a_second_training_to_the_same_out_is_refused_and_a_stale_lock_taken_over(tmp_path):
    from bowsynth.api import training_lock
    from bowsynth.errors import UsageError

    out = tmp_path / "m.safetensors"
    with training_lock(out):
        assert (tmp_path / "m.safetensors.lock").read_text() == str(os.getpid())
        with pytest.raises(UsageError, match="another training"):
            with training_lock(out):
                pass
    assert not (tmp_path / "m.safetensors.lock").exists()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / "m.safetensors.lock").write_text(dead.stdout.strip())  # its process has exited: stale
    with training_lock(out):
        pass


def test_a_file_that_appears_at_out_while_training_is_kept(tmp_path, tiny_model, recwarn):
    from bowsynth.api import _save_new
    from bowsynth.engines.operator.modelfile import load_model

    out = tmp_path / "m.safetensors"
    out.write_bytes(b"someone else's file")
    model = load_model(tiny_model)
    path = _save_new(model, out, force=False)
    assert out.read_bytes() == b"someone else's file"
    assert path == tmp_path / "m-1.safetensors" and load_model(path).id == model.id
    assert any("appeared while training" in str(w.message) for w in recwarn)
    assert _save_new(model, out, force=True) == out and load_model(out).id == model.id  # --force replaces


@pytest.mark.parametrize("kind, says", [("device", "is a device"), ("dir", "is a directory"), ("loop", "symlink loop"),
                                        ("fifo", "is a FIFO"), ("dangling", "symlink to nothing")])
def test_a_model_path_that_is_no_file_says_what_it_is(tmp_path, capsys, monkeypatch, kind, says):
    p = tmp_path / f"{kind}.safetensors"
    if kind == "device":
        p.symlink_to("/dev/zero")
    elif kind == "dir":
        p.mkdir()
    elif kind == "loop":
        p.symlink_to(p.name)
    elif kind == "fifo":
        os.mkfifo(p)
    else:
        p.symlink_to(tmp_path / "gone.safetensors")
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.1", "--model", str(p), str(tmp_path / "x.wav")],
                              capsys, monkeypatch)
    assert code != 0 and says in err and _one_line(err), err
    monkeypatch.chdir(tmp_path)  # the same file in ./models: the default lookup skips it and names it
    (tmp_path / "models").mkdir()
    os.rename(p, tmp_path / "models" / p.name)
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.1", str(tmp_path / "y.wav")], capsys, monkeypatch)
    assert code == 0 and "paper-fb100" in out


INPUTS = {  # a command that reads a file, and what it calls that file
    "compare": (["compare", "{f}"], "WAV file"),
    "score": (["score", "--score", "{f}", "--mix", "{d}/m.wav"], "score file"),  # no suffix: sniffed for MThd
    "score MIDI": (["score", "--score", "{f}.mid", "--mix", "{d}/m.wav"], "MIDI file"),
    "train --score": (["train", "--score", "{f}"], "score file"),
    "train --config": (["train", "--config", "{f}"], "--config"),
}


@pytest.mark.parametrize("kind, says", [("fifo", "is a FIFO"), ("dir", "is a directory"), ("device", "is a device"),
                                        ("dangling", "not found (a symlink to nothing)"), ("loop", "symlink loop")])
@pytest.mark.parametrize("command", list(INPUTS))
def test_an_input_that_is_no_file_says_what_it_is_and_never_blocks(tmp_path, command, kind, says):
    # a real process with a deadline: a FIFO opened to sniff its first bytes blocked `score` until someone wrote to
    # it; a directory, /dev/null or a shell's <(...) pipe were each "not found"
    args, what = INPUTS[command]
    f = tmp_path / "in"
    for p in (f, tmp_path / "in.mid"):
        if kind == "fifo":
            os.mkfifo(p)
        elif kind == "dir":
            p.mkdir()
        elif kind == "device":
            p.symlink_to("/dev/null")
        elif kind == "dangling":
            p.symlink_to(tmp_path / "gone")
        else:
            p.symlink_to(p.name)
    r = subprocess.run([sys.executable, "-m", "bowsynth", *[a.format(f=f, d=tmp_path) for a in args]],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2 and f"{what} {f}" in r.stderr and says in r.stderr and _one_line(r.stderr), r.stderr
    assert not (tmp_path / "m.wav").exists()


@pytest.mark.parametrize("start, force, code, says", [(3000.0, False, 2, "the mix would be 50 min long"),
                                                      (1e12, False, 2, "pass --force"),
                                                      (1e12, True, 1, "out of memory")])
def test_the_mix_is_estimated_as_a_whole_before_any_work(tmp_path, capsys, monkeypatch, start, force, code, says):
    (tmp_path / "late.toml").write_text(f'[[voice]]\nname = "v"\nf0 = 120.0\nbeta = 0.159155\nduration = 0.1\n'
                                        f'start = {start!r}\n')
    got, out, err = run_main(["score", "--score", str(tmp_path / "late.toml"), "--mix", str(tmp_path / "m.wav"),
                              *(["--force"] if force else [])], capsys, monkeypatch)
    assert got == code and says in err and _one_line(err), err
    assert not (tmp_path / "m.wav").exists()


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 kB tmpfs: a real full disk (needs root to mount; skipped where mounting is not allowed)."""
    d = tmp_path / "tiny"
    d.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(d)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    yield d
    subprocess.run(["umount", str(d)])


def test_a_full_disk_is_one_line_and_keeps_the_old_file(tiny_disk, capsys, monkeypatch):
    old = tiny_disk / "x.wav"
    old.write_bytes(b"the old file")
    code, out, err = run_main(["render", "--method", "fdm", "--fb", "100", "-d", "1", str(old)], capsys, monkeypatch)
    assert code == 1 and "disk is full" in err and _one_line(err), err
    assert old.read_bytes() == b"the old file" and sorted(p.name for p in tiny_disk.iterdir()) == ["x.wav"]


def test_no_usable_temp_dir_for_a_fifo_is_said_before_any_work(tmp_path, capsys, monkeypatch):
    import tempfile

    def none():
        raise FileNotFoundError("No usable temporary directory found")

    fifo = tmp_path / "out.wav"
    os.mkfifo(fifo)
    monkeypatch.setattr(tempfile, "gettempdir", none)
    code, out, err = run_main(["render", "--method", "fdm", "--fb", "100", "-d", "0.1", str(fifo)], capsys,
                              monkeypatch)
    assert code == 1 and "TMPDIR" in err and _one_line(err) and "wrote" not in out, err


def _forged(src, dst, edit_meta=None, edit_tensors=None):
    import json

    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(src), framework="pt") as f:
        meta = json.loads(f.metadata()["bowsynth_checkpoint"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    if edit_meta:
        edit_meta(meta)
    if edit_tensors:
        edit_tensors(tensors)
    save_file(tensors, str(dst), metadata={"bowsynth_checkpoint": json.dumps(meta)})
    return dst


@pytest.mark.parametrize("what", ["step -5", "step 1e18", "step text", "elapsed nan", "rng text", "tensor missing",
                                  "wrong shape", "nan weights", "rng state missing", "not a record"])
def test_a_forged_checkpoint_is_refused_in_one_line_never_an_internal_error(what, tmp_path):
    """A checkpoint is data from outside: wrong types, implausible steps or times, a missing or misshapen tensor,
    weights that are not finite: each a UsageError naming the file, before any of it is used."""
    import torch

    from bowsynth import Scene
    from bowsynth.api import make_train_config
    from bowsynth.errors import UsageError
    from bowsynth.training import Trainer

    sc = Scene(fb=100.0)
    cfg = make_train_config(sc, steps=3, width=8, depth=1, n_data=32)
    tr = Trainer(sc, cfg, "forged")
    good = tmp_path / "good.ckpt.safetensors"
    tr.save_checkpoint(good)
    Trainer(sc, cfg, "forged").load_checkpoint(good)  # the real one loads
    first = next(k for k in tr.net.state_dict() if k.endswith("weight"))
    edits = {
        "step -5": (lambda m: m.update(step=-5), None), "step 1e18": (lambda m: m.update(step=10**18), None),
        "step text": (lambda m: m.update(step="5"), None), "elapsed nan": (lambda m: m.update(elapsed=float("nan")), None),
        "rng text": (lambda m: m.update(rng="seed"), None),
        "tensor missing": (None, lambda t: t.pop(f"net.{first}")),
        "wrong shape": (None, lambda t: t.update({f"net.{first}": torch.zeros(3, 3)})),
        "nan weights": (None, lambda t: t[f"net.{first}"].fill_(float("nan"))),
        "rng state missing": (None, lambda t: t.pop("torch_rng")),
        "not a record": (lambda m: m.clear(), None),
    }
    bad = _forged(good, tmp_path / "bad.ckpt.safetensors", *edits[what])
    with pytest.raises(UsageError, match="bad.ckpt.safetensors"):
        Trainer(sc, cfg, "forged").load_checkpoint(bad)


def test_a_recipe_cycle_is_one_line_from_the_command_make_models_runs(tmp_path):
    (tmp_path / "a.toml").write_text('from = "b"\nfb = 100\n')
    (tmp_path / "b.toml").write_text('from = "a.safetensors"\nfb = 100\n')
    p = subprocess.run([sys.executable, "-m", "bowsynth.training.recipe", str(tmp_path / "a.toml"),
                        str(tmp_path / "b.toml")], capture_output=True, text=True, timeout=120)
    assert p.returncode == 1 and p.stderr.strip().startswith("error: recipes refine each other in a cycle")
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr


def test_a_fifo_in_a_training_files_place_is_refused_before_anything_opens_it(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    os.mkfifo(models / "x.ckpt.safetensors")
    for flag in ("--resume", "--force"):
        p = subprocess.run([sys.executable, "-m", "bowsynth", "train", "--fb", "100", "--steps", "3", "--width", "8",
                            "--depth", "1", "--n-data", "32", "--out", str(models / "x.safetensors"), flag],
                           capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert p.returncode == 2 and "not a regular file" in p.stderr, p.stderr
    assert stat.S_ISFIFO(os.stat(models / "x.ckpt.safetensors").st_mode) and not (models / "x.safetensors").exists()
