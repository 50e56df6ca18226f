"""The whole CLI path through typer's CliRunner: train, render, compare, and the one-line errors."""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from conftest import run_main, shipped_models, shipped_pick
from typer.testing import CliRunner

from bowsynth.cli.main import app
from bowsynth.io.audio import read_wav

runner = CliRunner()


def test_train_render_compare(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    model = tmp_path / "m.safetensors"
    code, out, err = run_main(["train", "--fb", "100", "--steps", "400", "--width", "16", "--depth", "2", "--n-data",
                               "256", "--optimizer", "adam", "--out", str(model), "--quiet"], capsys, monkeypatch)
    assert code == 0, err
    assert "model written to" in out and model.exists()
    # a tiny model may leave its domain in validation; train says so instead of printing a score
    assert "NMSE(p)" in out or "validation failed: the rollout left" in err
    # never overwrite without --force
    code, _, err = run_main(["train", "--fb", "100", "--steps", "5", "--out", str(model), "--quiet"], capsys, monkeypatch)
    assert code == 2 and "--force" in err and err.count("\n") == 1
    wav = tmp_path / "out.wav"
    code, out, err = run_main(["render", "--fb", "100", "--duration", "0.3", "--model", str(model),
                               "--fallback", "fdm", str(wav)], capsys, monkeypatch)
    assert code == 0, err
    assert "real time" in out
    info = read_wav(wav)
    assert info.meta["method"].startswith("operator") and info.meta["model"].startswith("fb100")
    assert info.scene.fb == 100 and info.sample_rate == 44100
    # the file holds what the API renders (float32 samples scaled to their peak)
    from bowsynth import load_model, render_fdm, render_operator
    from bowsynth.metrics import nmse
    from bowsynth.io.audio import remove_dc

    assert info.dc_removed  # the default: the static offset is not sound
    expect = remove_dc(render_operator(info.scene, model=load_model(model), fallback="fdm").u, info.sample_rate)
    np.testing.assert_allclose(info.physical, expect, rtol=0, atol=1e-6 * np.abs(expect).max())
    code, out, err = run_main(["compare", str(wav), "--json"], capsys, monkeypatch)
    assert code == 0, err
    j = json.loads(out)
    m = j["metrics"]["file vs FDM"]
    assert {"nmse", "ncc_percent", "cents"} <= set(m) and "render_seconds" in j
    # compare reports the file's error against the audio-rate FDM (its DC removed as the file's was), not some
    # other number
    assert m["nmse"] == pytest.approx(nmse(info.physical, remove_dc(render_fdm(info.scene).u, info.sample_rate)),
                                      rel=1e-9)


def test_fdm_wav_compares_to_zero(tmp_path, monkeypatch, capsys):
    wav = tmp_path / "f.wav"
    code, _, err = run_main(["render", "--method", "fdm", "--fb", "100", "-d", "0.5", "--signal", "p", str(wav)],
                            capsys, monkeypatch)
    assert code == 0, err
    png = tmp_path / "plot.png"
    code, out, err = run_main(["compare", str(wav), "--json", "--plot", str(png)], capsys, monkeypatch)
    assert code == 0, err
    m = json.loads(out)["metrics"]["file vs FDM"]
    assert m["nmse"] < 1e-12 and abs(m["cents"]) < 1e-6
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # two files directly
    code, out, err = run_main(["compare", str(wav), str(wav), "--json"], capsys, monkeypatch)
    assert code == 0 and json.loads(out)["metrics"][f"{wav.name} vs {wav.name}"]["nmse"] == 0


def test_metadata_round_trip_after_move(tmp_path):
    from bowsynth import Scene, render_fdm
    from bowsynth.io.audio import remove_dc, write_wav

    sc = Scene(fb=30, vb=0.15, f0=123.5, duration=0.2, sample_rate=48000, q0=0.01)
    r = render_fdm(sc)
    write_wav(tmp_path / "a.wav", r)
    os.rename(tmp_path / "a.wav", tmp_path / "b.wav")
    info = read_wav(tmp_path / "b.wav")
    assert info.scene == sc and info.meta["method"] == "fdm" and info.meta["signal"] == "u"
    assert info.dc_removed  # by default the written signal is the render with its DC removed
    clean = remove_dc(r.u, sc.sample_rate)
    np.testing.assert_allclose(info.physical, clean, rtol=1e-6, atol=1e-7 * np.abs(clean).max())
    write_wav(tmp_path / "k.wav", r, dc="keep")
    kept = read_wav(tmp_path / "k.wav")
    assert not kept.dc_removed
    np.testing.assert_allclose(kept.physical, r.u, rtol=1e-6, atol=1e-7 * np.abs(r.u).max())
    assert not list(tmp_path.glob(".*tmp"))  # no temp file left behind


def test_no_model_covers_scene(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("bowsynth.engines.operator.choose.SHIPPED_DIR", tmp_path / "none")
    code, _, err = run_main(["render", "--fb", "123", "--vb", "0.3", str(tmp_path / "x.wav")], capsys, monkeypatch)
    assert code == 1
    assert "no model covers" in err and "bowsynth train --fb 123 --f0 100 --vb 0.3 --a 100" in err
    assert err.count("\n") == 1 and not (tmp_path / "x.wav").exists()


def test_a_range_render_says_how_long_its_model_was_validated(tmp_path, monkeypatch, capsys):
    """A range render states how long the model it picked was validated from rest, from that model's own record, in
    the phrase train printed (one rule for both: cli.app.range_validation_text). The two bows' picks were validated
    over different lengths (a box whose notes take seconds to grow over longer), so a fixed phrase cannot pass."""
    from bowsynth.cli.app import range_validation_text
    from bowsynth.scene import Scene

    monkeypatch.chdir(tmp_path)  # no ./models: the renderer picks among the shipped models
    lengths = []
    for fb, vb in (("55.3", "0.28"), ("300", "0.2")):
        m = shipped_pick(Scene(f0=440, fb=float(fb), vb=float(vb), duration=0.2))
        v = m.meta.validation
        assert m.domain.is_range, m.path.stem
        code, out, err = run_main(["render", "--f0", "440", "--fb", fb, "--vb", vb, "-d", "0.2", "x.wav", "--force"],
                                  capsys, monkeypatch)
        said = out + err
        assert code == 0 and m.path.stem in said, said
        assert f"its validation ({v['seconds']:g} s from rest on a 3 x 3 grid" in said, said
        assert f"its {range_validation_text(v, 'its')}" in said and "FDM x100, where the note speaks" in said, said
        lengths.append(v["seconds"])
    assert lengths[0] != lengths[1], lengths


def test_model_by_name(tmp_path, tiny_model, monkeypatch, capsys):
    """--model takes a model's name in ./models (before the shipped ones) as well as a file; an unknown name is one
    line naming the models there are, exit 1, nothing written."""
    import shutil

    monkeypatch.chdir(tmp_path)
    (tmp_path / "models").mkdir()
    shutil.copy(tiny_model, tmp_path / "models" / "mine.safetensors")
    wav = tmp_path / "x.wav"
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.05", "--model", "mine", str(wav)], capsys, monkeypatch)
    assert code == 0, err
    assert str(tmp_path / "models" / "mine.safetensors") in out and wav.exists()
    score = tmp_path / "s.toml"
    score.write_text('[[voice]]\nname = "a"\nfb = 100.0\nduration = 0.05\n')
    code, out, err = run_main(["score", "--score", str(score), "--model", "mine", "--mix", str(tmp_path / "m.wav")],
                              capsys, monkeypatch)
    assert code == 0, err
    code, _, err = run_main(["render", "--fb", "100", "-d", "0.05", "--model", "nosuch", str(tmp_path / "y.wav")],
                            capsys, monkeypatch)
    assert code == 1 and err.count("\n") == 1
    assert "model nosuch not found" in err and "mine" in err
    assert all(m.path.stem in err for m in shipped_models()), err  # and every shipped model's name
    assert not (tmp_path / "y.wav").exists()


def test_rollout_forced_out_of_domain_stops_cleanly(tmp_path, tiny_model, monkeypatch, capsys):
    from bowsynth import Scene, render_operator
    from bowsynth.engines.operator.modelfile import load_model

    m = load_model(tiny_model)
    # shrink the domain around the start so the rollout leaves it within the first windows
    d = m.domain
    d.mask[:] = False
    d.mask[d.mask.shape[0] // 2 - 1: d.mask.shape[0] // 2 + 1, :] = True
    d.q_lo, d.q_hi = -1e-3, 1e-3
    small = tmp_path / "small.safetensors"
    m.save(small)
    wav = tmp_path / "y.wav"
    code, _, err = run_main(["render", "--fb", "100", "-d", "0.2", "--model", str(small), str(wav)], capsys, monkeypatch)
    assert code == 1 and "left the model's trained states" in err and "--fallback fdm" in err
    assert not wav.exists()
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.2", "--model", str(small), "--fallback", "fdm",
                               str(wav)], capsys, monkeypatch)
    assert code == 0 and "finished with the FDM" in out
    from bowsynth.io.audio import remove_dc

    expect = remove_dc(render_operator(Scene(fb=100, duration=0.2), model=small, fallback="fdm").u, 44100)
    np.testing.assert_allclose(read_wav(wav).physical, expect, rtol=0, atol=1e-6 * np.abs(expect).max())


def test_help_everywhere():
    for cmd in ("render", "train", "compare", "bench", "models", "presets"):
        r = runner.invoke(app, [cmd, "--help"])
        assert r.exit_code == 0 and "Usage" in r.output
    assert "m/s^2" in runner.invoke(app, ["render", "--help"]).output


@pytest.mark.parametrize("args,why", [(["--fb", "50:200"], "point models"), (["--fb", "1000"], "too strongly")],
                         ids=["range", "driven-hard"])
def test_rest_linear_is_refused_where_it_cannot_apply(args, why, tmp_path, capsys, monkeypatch):
    out = tmp_path / "m.safetensors"
    code, _, err = run_main(["train", *args, "--rest-linear", "--steps", "1", "--out", str(out), "-q"], capsys,
                            monkeypatch)
    assert code == 2 and why in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_shipped_recipes_name_their_models_and_train_flags(tmp_path):
    from bowsynth.training.recipe import load_recipe

    models = Path(__file__).resolve().parents[1] / "models"
    recipes = sorted(models.glob("*.toml"))
    assert {r.stem for r in recipes} == {m.stem for m in models.glob("*.safetensors")}
    # the stages a shipped refinement was made through, kept to rebuild it and never picked by a render
    stages = sorted((models / "stages").glob("*.toml"))
    assert {r.stem for r in stages} == {m.stem for m in (models / "stages").glob("*.safetensors")} and stages
    from bowsynth.cli.train import recipe_status

    for r in recipes + stages:
        rec = load_recipe(r)
        assert rec["out"] == r.with_suffix(".safetensors") and 0 < rec["minutes"] <= 45
        # every shipped model is what its recipe makes (a refinement: from its base as shipped, its window kept)
        assert recipe_status(r) is None, (r.name, recipe_status(r))


def test_make_models_builds_each_refinement_after_the_model_it_refines(tmp_path, monkeypatch):
    """build_order, what `make models` loops over: a chain of refinements (a stage, its refinement, a refinement of
    that) in the order they must be trained, whatever order the files come in and whether or not any model file
    exists yet; the shipped recipes likewise; a cycle refused."""
    import subprocess
    import sys

    from bowsynth.errors import UsageError
    from bowsynth.training.recipe import build_order

    for name, parent in (("a", None), ("b", "a"), ("c", "b"), ("d", None)):
        (tmp_path / f"{name}.toml").write_text(f'preset = "paper-fb100"\nout = "{name}.safetensors"\n'
                                               + (f'from = "{parent}.safetensors"\n' if parent else ""))
    given = [tmp_path / f"{n}.toml" for n in "cdba"]
    assert [p.stem for p in build_order(given)] == ["a", "b", "c", "d"]
    # paths relative to the working folder, as `make models` gives them, with the parents' files present
    (tmp_path / "a.safetensors").write_bytes(b"")
    (tmp_path / "b.safetensors").write_bytes(b"")
    rel = [Path(tmp_path.name) / p.name for p in given]
    monkeypatch.chdir(tmp_path.parent)
    assert [p.stem for p in build_order(rel)] == ["a", "b", "c", "d"]
    repo = Path(__file__).resolve().parents[1]
    models = repo / "models"
    shipped = sorted((models / "stages").glob("*.toml")) + sorted(models.glob("*.toml"))
    out = subprocess.run([sys.executable, "-m", "bowsynth.training.recipe",
                          *(str(p.relative_to(repo)) for p in shipped)], capture_output=True, text=True, check=True,
                         cwd=repo).stdout.split()
    order = [(repo / p).resolve() for p in out]
    assert sorted(order) == sorted(p.resolve() for p in shipped)
    from bowsynth.training.recipe import load_recipe

    base = {}  # each shipped refinement's recipe: the recipe of the model it refines
    for i, p in enumerate(order):
        rec = load_recipe(p)
        if "from" in rec and (p.parent / rec["from"]).resolve().with_suffix(".toml") in order:
            base[p] = (p.parent / rec["from"]).resolve().with_suffix(".toml")
            assert order.index(base[p]) < i, p.name
    # the shipped recipes hold such chains: a refinement of a refinement, and a model refined from a stage
    assert any(base.get(b) is not None for b in base.values()), base
    assert any(b.parent == models / "stages" and p.parent == models for p, b in base.items()), base
    (tmp_path / "a.toml").write_text('preset = "paper-fb100"\nout = "a.safetensors"\nfrom = "c.safetensors"\n')
    with pytest.raises(UsageError, match="cycle"):
        build_order(given)


def test_train_update_builds_what_is_missing_stale_or_unreadable_and_leaves_the_rest(tmp_path, capsys, monkeypatch):
    """`make models` runs `train --config R --update` for each recipe: a model that is what its recipe asks for is
    left as it is; a missing, stale or truncated one is trained (replaced); an interrupted run's checkpoint is
    continued, not started over."""
    from bowsynth import api, make_scene
    from bowsynth.engines.operator.modelfile import load_model
    from bowsynth.training import Trainer
    from bowsynth.training.config import checkpoint_path

    rec, model = tmp_path / "r.toml", tmp_path / "m.safetensors"
    rec.write_text('preset = "paper-fb100"\nsteps = 2\nwidth = 4\nout = "m.safetensors"\n')
    tiny = ["--n-data", "16", "--depth", "1"]

    def update():
        code, out, err = run_main(["train", "--config", str(rec), "--update", *tiny], capsys, monkeypatch)
        assert code == 0 and "Traceback" not in err, err
        return out + err

    assert "m.safetensors: missing; training it" in update() and model.exists()
    first = model.read_bytes()
    assert "is up to date with" in update() and model.read_bytes() == first
    rec.write_text(rec.read_text().replace("steps = 2", "steps = 2\nseed = 3"))
    said = update()
    assert "stale: trained with seed 0, the recipe asks for 3" in said and load_model(model).meta.training["seed"] == 3
    model.write_bytes(model.read_bytes()[:300])  # truncated, as by a full disk
    assert "unreadable" in update() and load_model(model).meta.training["seed"] == 3
    # an interrupted run: its checkpoint after one step is continued to the recipe's two
    rec.write_text(rec.read_text().replace("seed = 3", "seed = 4"))
    scene = make_scene("paper-fb100")
    cfg = api.make_train_config(scene, steps=2, seed=4, n_data=16, width=4, depth=1)
    tr = Trainer(scene, cfg, load_model(model).meta.name)
    tr.cfg.steps = 1
    tr.run()
    tr.save_checkpoint(checkpoint_path(model))
    said = update()
    assert "continuing from its checkpoint" in said and not checkpoint_path(model).exists()
    m = load_model(model)
    assert m.meta.training["seed"] == 4 and m.meta.training["steps_done"] == 2
    code, _, err = run_main(["train", "--preset", "paper-fb100", "--update", "--steps", "1"], capsys, monkeypatch)
    assert code == 2 and "--update compares a model file with its recipe" in err and len(err.strip().splitlines()) == 1


def test_models_names_a_shipped_unit_that_is_missing_or_stale_and_lists_the_rest(tmp_path, capsys, monkeypatch):
    """Three shipped units in a shipped folder of their own: one as shipped, one whose recipe asks for a minute more
    of training, one whose model file is gone. They are models trained from scratch: a refinement's recipe names its
    base, which is not in that folder."""
    import re
    import shutil

    from bowsynth.training.recipe import load_recipe

    shipped = tmp_path / "shipped"
    shipped.mkdir()
    kept, stale, gone = [m for m in shipped_models() if "from" not in load_recipe(m.path.with_suffix(".toml"))][:3]
    for m in (kept, stale):
        shutil.copy(m.path, shipped)
        shutil.copy(m.path.with_suffix(".toml"), shipped)
    shutil.copy(gone.path.with_suffix(".toml"), shipped)  # its model is gone
    more = load_recipe(stale.path.with_suffix(".toml"))["minutes"] + 1
    recipe = shipped / stale.path.with_suffix(".toml").name
    recipe.write_text(re.sub(r"(?m)^minutes = .*$", f"minutes = {more}", recipe.read_text()))
    monkeypatch.setattr("bowsynth.engines.operator.choose.SHIPPED_DIR", shipped)
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["models", "--long"], capsys, monkeypatch)
    lines = out.splitlines()
    assert code == 0, err
    assert any(f"/{gone.path.name}" in ln and "MISSING" in ln and "make models" in ln for ln in lines), out
    was = stale.meta.training["minutes"]
    assert any(f"/{stale.path.name}" in ln and f"stale: trained with minutes {was}, the recipe asks for {more}" in ln
               for ln in lines), out
    assert not any(f"/{kept.path.name}" in ln and ("stale" in ln or "MISSING" in ln) for ln in lines), out
    assert sum(kept.id in ln for ln in lines) == 1  # the current unit is listed as usual


def test_a_model_of_damped_bows_says_it_rests_where_render_and_models_state_its_validation(tmp_path, capsys,
                                                                                           monkeypatch):
    """A shipped model whose grid bows all damp the mass (choose.rests_throughout) has no pitch or NMSE to state,
    only that it rests at every grid bow: so `models --long` says, and so does a render at its centre bow, where
    the renderer picks such a model."""
    from bowsynth.engines.operator.choose import rests_throughout
    from bowsynth.scene import Scene

    m = next(m for m in shipped_models() if m.failure is None and m.domain.is_range and rests_throughout(m))
    code, out, err = run_main(["models", "--long"], capsys, monkeypatch)
    lines = out.splitlines()
    line = lines[next(i for i, ln in enumerate(lines) if f"/{m.path.name}" in ln) + 1]  # its details
    b0, b1, v0, v1 = m.domain.box
    assert f"F_B/w {b0:.4g}..{b1:.4g}" in line and f"vb {v0:g}..{v1:g}" in line, line
    grid = m.meta.validation["grid"] ** 2
    assert code == 0 and f"the model rests at {grid:g} of {grid:g}" in line and "n/a" not in line, line
    fb = f"{m.domain.beta * 2 * math.pi * 110:.1f}"
    pick = shipped_pick(Scene(f0=110, fb=float(fb), vb=m.domain.vb, duration=0.5))
    assert rests_throughout(pick), pick.path.stem
    grid = pick.meta.validation["grid"] ** 2
    code, out, err = run_main(["render", "--f0", "110", "--fb", fb, "--vb", f"{m.domain.vb:g}", "-d", "0.5",
                               str(tmp_path / "rest.wav")], capsys, monkeypatch)
    assert code == 0 and pick.path.stem in out and f"the model rests at {grid:g} of {grid:g}" in out, out + err
    assert "n/a" not in out, out + err


def test_train_config_refuses_unknown_keys_and_bad_types(tmp_path, capsys, monkeypatch):
    bad = tmp_path / "bad.toml"
    for text, what in [("fb = 100\nminute = 5\n", "unknown key 'minute'"), ("minutes = \"ten\"\n", "minutes must be"),
                       ("fb = [1, 2\n", "not valid TOML")]:
        bad.write_text(text)
        code, out, err = run_main(["train", "--config", str(bad)], capsys, monkeypatch)
        assert code == 2 and what in err and "Traceback" not in err, err
    code, out, err = run_main(["train", "--config", str(tmp_path / "none.toml")], capsys, monkeypatch)
    assert code == 2 and "not found" in err


def test_train_batch_width_window_and_device_from_a_recipe_and_the_device_is_recorded(tmp_path, capsys,
                                                                                     monkeypatch):
    from bowsynth.cli.train import recipe_status
    from bowsynth.engines.operator.modelfile import load_model

    rec = tmp_path / "r.toml"
    rec.write_text('fb = 100\nsteps = 2\nbatch = 64\nwidth = 8\ndevice = "cpu"\nwindow_ms = 2.5\n'
                   'out = "m.safetensors"\n')
    code, out, err = run_main(["train", "--config", str(rec), "--n-data", "64", "-q"], capsys, monkeypatch)
    assert code == 0, err
    m = load_model(tmp_path / "m.safetensors")
    assert m.meta.training["batch_states"] == 64 and m.meta.net["width"] == 8
    assert m.meta.training["device"] == "cpu" and m.meta.training["device_used"].startswith("cpu: ")
    # 2.5 ms at f0 100 is a quarter of the free period (the stick-slip tiles' windows)
    assert m.meta.training["window"] == pytest.approx(math.pi / 2) and m.domain.window == pytest.approx(math.pi / 2)
    assert recipe_status(rec) is None
    rec.write_text(rec.read_text().replace("window_ms = 2.5", "window_ms = 5"))
    assert "stale: trained with window 1.57" in recipe_status(rec)
    rec.write_text(rec.read_text().replace("window_ms = 5", 'window_ms = "short"'))
    code, out, err = run_main(["train", "--config", str(rec), "-q"], capsys, monkeypatch)
    assert code == 2 and "window_ms must be int or float" in err, err


def test_a_range_recipe_with_a_longer_band_is_judged_as_long_and_its_band_is_part_of_the_recipe(tmp_path, capsys,
                                                                                                  monkeypatch):
    from bowsynth.cli.train import recipe_status
    from bowsynth.engines.operator.modelfile import load_model

    rec = tmp_path / "r.toml"
    rec.write_text('fb = "60:80"\nvb = "0.2:0.22"\nsteps = 2\nbatch = 64\nwidth = 8\nband_seconds = 1.5\n'
                   'out = "m.safetensors"\n')
    code, out, err = run_main(["train", "--config", str(rec), "--n-data", "64"], capsys, monkeypatch)
    assert code == 0, err
    m = load_model(tmp_path / "m.safetensors")
    assert m.meta.training["band_seconds"] == 1.5 and m.meta.validation["seconds"] == 1.5
    assert "validating: 1.5 s rollouts on a 3 x 3 grid" in err, err
    assert recipe_status(rec) is None
    rec.write_text(rec.read_text().replace("band_seconds = 1.5", "band_seconds = 2"))
    assert "stale: trained with band_seconds 1.5, the recipe asks for 2" in recipe_status(rec)
    for bad in ("0", "31", "nan"):
        code, out, err = run_main(["train", "--fb", "60:80", "--steps", "1", "--band-seconds", bad], capsys,
                                  monkeypatch)
        assert code == 2 and "--band-seconds must be > 0 and at most 30" in err and "Traceback" not in err, err


def test_a_point_recipe_names_its_derivative_weight_and_the_model_trains_with_it(tmp_path, capsys, monkeypatch):
    from bowsynth.cli.train import recipe_status
    from bowsynth.engines.operator.modelfile import load_model

    rec = tmp_path / "r.toml"
    rec.write_text('fb = 100\nsteps = 2\nbatch = 64\nwidth = 8\nout = "m.safetensors"\n')
    code, out, err = run_main(["train", "--config", str(rec), "--n-data", "64", "-q"], capsys, monkeypatch)
    assert code == 0, err
    assert "deriv" not in load_model(tmp_path / "m.safetensors").meta.training["weights"]  # a point model's default
    assert recipe_status(rec) is None
    rec.write_text(rec.read_text() + "deriv = 0.05\n")
    assert "stale: trained with deriv 0.0, the recipe asks for 0.05" in recipe_status(rec)
    code, out, err = run_main(["train", "--config", str(rec), "--n-data", "64", "-q", "--force"], capsys, monkeypatch)
    assert code == 0, err
    m = load_model(tmp_path / "m.safetensors")
    assert m.meta.training["weights"]["deriv"] == 0.05 and m.meta.training["deriv"] == 0.05
    assert recipe_status(rec) is None
    rec.write_text(rec.read_text().replace("deriv = 0.05", "deriv = 0"))
    assert "stale: trained with deriv 0.05, the recipe asks for 0" in recipe_status(rec)
    for bad in ("-0.1", "101", "nan"):
        code, out, err = run_main(["train", "--fb", "100", "--steps", "1", "--deriv", bad], capsys, monkeypatch)
        assert code == 2 and "--deriv must be in [0, 100]" in err and "Traceback" not in err, err


@pytest.mark.parametrize("args, needle", [(["--device", "gpu"], "--device must be auto, cpu or cuda"),
                                          (["--batch", "0"], "--batch must be in"),
                                          (["--device", "cuda"], "torch sees no CUDA GPU")])
def test_train_refuses_a_device_it_cannot_use_in_one_line(args, needle, tmp_path, capsys, monkeypatch):
    import torch

    if args[-1] == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    out = tmp_path / "m.safetensors"
    code, _, err = run_main(["train", "--fb", "100", "--steps", "1", *args, "--out", str(out), "-q"], capsys,
                            monkeypatch)
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_train_config_fills_flags_and_flags_override(tmp_path, capsys, monkeypatch):
    rec = tmp_path / "r.toml"
    rec.write_text('preset = "paper-fb100"\nsteps = 3\nseed = 1\nout = "m.safetensors"\n')
    code, out, err = run_main(["train", "--config", str(rec), "--steps", "2", "-q"], capsys, monkeypatch)
    assert code == 0, err
    from bowsynth.engines.operator.modelfile import load_model

    m = load_model(tmp_path / "m.safetensors")  # out resolved against the recipe's folder
    assert m.meta.scene["fb"] == 100 and m.meta.training["steps_done"] == 2


def test_models_is_a_table_of_where_each_model_plays_and_draws_the_tiling(tmp_path, capsys, monkeypatch):
    """`bowsynth models`: a row a model (its box of F_B / w and v_B, its windows, its validation or why it failed,
    its size), whole lines in a pipe; --map draws the tiling to a PNG, and refuses another kind of file."""
    from bowsynth.engines.operator.choose import available_models

    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["models", "--map", str(tmp_path / "atlas.png")], capsys, monkeypatch)
    assert code == 0, err
    rows = {ln.split()[0]: ln for ln in out.splitlines()[1:] if ln.strip() and not ln.startswith("map written")}
    for m in available_models():
        row = rows[m.path.stem]
        if m.domain.is_range:
            b0, b1, v0, v1 = m.domain.box
            assert f"{b0:.3g}-{b1:.3g}" in row and f"{v0:.3g}-{v1:.3g}" in row, row
        assert ("FAILED" in row) == (m.failure is not None), row
    assert (tmp_path / "atlas.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code, out, err = run_main(["models", "--map", str(tmp_path / "atlas.txt")], capsys, monkeypatch)
    assert code == 2 and "PNG" in err and not (tmp_path / "atlas.txt").exists()
