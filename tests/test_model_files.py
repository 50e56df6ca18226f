"""Model files: read without torch, metadata bound to the weights, physics checked at render time, the best
validated model picked, the lookup cached per process."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_main, shipped_models, shipped_pick, soft_bow_model

from bowsynth import ModelFileError, Scene
from bowsynth.engines.operator import npnet
from bowsynth.engines.operator.check import PHYSICS_MAX_ERROR, check_physics
from bowsynth.engines.operator.choose import SHIPPED_DIR, available_models
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import OperatorModel, digest, load_model

# the shipped point model the renderer picks for the paper's F_B 100 scene: the file these tests copy, edit and forge
FB100 = SHIPPED_DIR / shipped_pick(Scene(fb=100)).path.name
assert not load_model(FB100).domain.is_range, FB100
ROOT = Path(__file__).resolve().parents[1]


def rewrite(src, dst, edit, fix_digest=True, version=None):
    """Copy a model file with its metadata changed by edit(meta); fix_digest recomputes the digest as a forger would
    (so that only the physics check can tell); version=1 writes a format-1 file (no digest)."""
    from safetensors import safe_open
    from safetensors.numpy import save_file

    with safe_open(str(src), framework="numpy") as f:
        meta = json.loads(f.metadata()["bowsynth"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    edit(meta)
    if version == 1:
        meta["format_version"] = 1
        meta.pop("digest", None)
    elif fix_digest:
        meta["digest"] = digest(meta, tensors)
    save_file(tensors, str(dst), metadata={"bowsynth": json.dumps(meta)})
    return dst


def claim_double_force(meta):
    meta["domain"]["beta"] *= 2
    meta["scene"]["fb"] *= 2


def test_numpy_network_matches_torch():
    m = load_model(FB100)
    net = m.net  # built from the file's weights on first use
    s = np.linspace(0, 1.01, 301)
    x0 = np.random.default_rng(0).uniform(-0.3, 0.3, size=(50, 2))
    with torch.no_grad():
        t_trunk = net.trunk_features(torch.tensor(s, dtype=torch.float32)).double().numpy()
        t_branch = net.branch_features(torch.tensor(x0, dtype=torch.float32)).double().numpy()
    n_trunk = npnet.trunk_features(m.weights, m.cfg, s)
    n_branch = npnet.branch_features(m.weights, m.cfg, x0)
    assert np.abs(n_trunk - t_trunk).max() < 1e-6 * np.abs(t_trunk).max()
    assert np.abs(n_branch - t_branch).max() < 1e-6 * np.abs(t_branch).max()
    # in float64 on both sides the two are the same function to rounding
    net64 = m.net.double()
    with torch.no_grad():
        t64 = net64.trunk_features(torch.tensor(s)).numpy()
    assert np.abs(n_trunk - t64).max() < 1e-12 * np.abs(t64).max()


def test_rollout_from_a_file_equals_the_torch_built_model(tmp_path):
    from safetensors.torch import load_file

    from bowsynth.engines.operator.network import DeepONet, NetConfig

    loaded = load_model(FB100)
    tensors = load_file(str(FB100))
    tensors.pop("domain.mask")
    net = DeepONet(NetConfig(**loaded.meta.net))
    net.load_state_dict(tensors)
    built = OperatorModel(net, loaded.meta)  # as the trainer builds it
    for sc in (Scene(fb=100, duration=0.3), Scene(fb=200, f0=200, duration=0.3)):
        a, b = render_operator(sc, model=loaded), render_operator(sc, model=built)
        assert np.array_equal(a.q, b.q) and np.array_equal(a.p, b.p)
    out = built.save(tmp_path / "again.safetensors")  # saving needs no torch either way, same id
    again = load_model(out)
    assert again.id == loaded.id and again.meta.format_version == 2
    assert all(np.array_equal(again.weights[k], v) for k, v in loaded.weights.items())


def test_render_imports_neither_torch_nor_scipy(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-X", "importtime", "-m", "bowsynth", "render", "--fb", "100", "-d", "1",
                        str(tmp_path / "x.wav")], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    modules = {line.split("|")[-1].strip().split(".")[0] for line in r.stderr.splitlines() if "import time:" in line}
    assert "numpy" in modules and "safetensors" in modules  # the listing is real
    assert "torch" not in modules and "numba" not in modules and "scipy" not in modules
    assert f"({FB100})" in r.stdout and "fb100_f0100_vb0.2_a100@" in r.stdout


@pytest.fixture
def listed_dir(tmp_path, monkeypatch):
    """A directory standing for the shipped one, its manifest beside its files (written by the test)."""
    from bowsynth.engines.operator import manifest

    d = tmp_path / "shipped"
    d.mkdir()
    monkeypatch.setattr(manifest, "MANIFEST", d / "MANIFEST.json")
    manifest._listed.cache_clear()
    yield d
    manifest._listed.cache_clear()


def test_a_files_digest_is_checked_at_every_read_and_never_taken_from_the_cache(tmp_path, monkeypatch):
    """A file of ./models is hashed whole each time it is read: one weight changed in place after a clean read (its
    modification time set back, its size the same) is refused, whatever the cache holds; so is a file whose digest
    was taken out."""
    import shutil

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "m.safetensors"
    shutil.copyfile(FB100, path)
    load_model(path)
    st = path.stat()
    with open(path, "r+b") as fh:
        fh.seek(-100, os.SEEK_END)
        b = fh.read(1)
        fh.seek(-100, os.SEEK_END)
        fh.write(bytes([b[0] ^ 0x40]))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert path.stat().st_size == st.st_size and path.stat().st_mtime_ns == st.st_mtime_ns
    with pytest.raises(ModelFileError, match="metadata does not match the weights"):
        load_model(path)
    with pytest.raises(ModelFileError, match="metadata does not match the weights"):
        load_model(rewrite(FB100, tmp_path / "d.safetensors", lambda m: m.pop("digest"), fix_digest=False))


def test_a_listed_file_is_read_by_its_header_and_its_weights_only_when_a_render_needs_them(listed_dir):
    """A process looks up a model among every file's header; a file the manifest lists gives its weights on first use
    (hashed against its digest then), the same arrays an eager read gives, and the same render."""
    import shutil

    from safetensors.numpy import load_file

    from bowsynth.training.manifest import write_manifest

    path = listed_dir / "m.safetensors"
    shutil.copyfile(FB100, path)
    eager = load_model(path)  # not listed yet: checked whole
    write_manifest(listed_dir)
    lazy = load_model(path)
    assert eager._weights is not None and lazy._weights is None
    want = {k: v for k, v in load_file(str(path)).items() if k != "domain.mask"}
    got = lazy.weights
    assert set(got) == set(want) and all(np.array_equal(got[k], want[k]) for k in want)
    scene = Scene(fb=100.0, duration=0.05)
    assert np.array_equal(render_operator(scene, model=load_model(path)).p, render_operator(scene, model=eager).p)


def test_a_file_replaced_after_its_header_was_read_is_refused_not_played(listed_dir, capsys, monkeypatch):
    """The weights are read from the file whose header was checked or not at all: a file put in its place (a rename
    over it, as a training's --force does) between the lookup and the render is refused in one line."""
    import shutil

    from bowsynth.training.manifest import write_manifest

    path = listed_dir / "m.safetensors"
    shutil.copyfile(FB100, path)
    write_manifest(listed_dir)
    model = load_model(path)
    other = listed_dir.parent / "other.safetensors"
    shutil.copyfile(next(m.path for m in shipped_models() if m.id != model.id), other)
    os.replace(other, path)
    with pytest.raises(ModelFileError, match="changed since bowsynth read it"):
        render_operator(Scene(fb=100.0, duration=0.05), model=model)
    assert load_model(path).meta.id != model.meta.id  # read afresh, it is the new file


def test_metadata_edited_without_the_digest_is_refused(tmp_path):
    with pytest.raises(ModelFileError, match="metadata does not match the weights: the file was edited"):
        load_model(rewrite(FB100, tmp_path / "a.safetensors", claim_double_force, fix_digest=False))
    with pytest.raises(ModelFileError, match="metadata does not match the weights"):
        load_model(rewrite(FB100, tmp_path / "b.safetensors", lambda m: m["validation"].update(nmse=1e-12),
                           fix_digest=False))
    # one weight changed, the metadata left alone
    data = bytearray(FB100.read_bytes())
    data[-100] ^= 0x40
    (tmp_path / "c.safetensors").write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match="metadata does not match the weights"):
        load_model(tmp_path / "c.safetensors")


@pytest.mark.parametrize("version", [2, 1], ids=["digest-forged", "format-1-no-digest"])
def test_a_file_claiming_another_bow_force_is_refused_by_its_physics(tmp_path, monkeypatch, capsys, version):
    models = tmp_path / "models"
    models.mkdir()
    lie = rewrite(FB100, models / "liar.safetensors", claim_double_force, version=version)
    m = load_model(lie)  # the file itself is consistent
    assert m.domain.beta == pytest.approx(2 * load_model(FB100).domain.beta) and m.covers(Scene(fb=200))
    assert check_physics(m) > 0.1
    monkeypatch.chdir(tmp_path)
    for extra in ([], ["--model", str(lie)]):
        code, out, err = run_main(["render", "--fb", "200", "-d", "0.2", *extra, str(tmp_path / "x.wav")],
                                  capsys, monkeypatch)
        assert code == 1 and "does not do what it claims" in err and "liar.safetensors" in err
        assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.wav").exists()
    # the honest shipped model still renders its own force from the same directory
    code, out, _ = run_main(["render", "--fb", "100", "-d", "0.2", str(tmp_path / "y.wav")], capsys, monkeypatch)
    assert code == 0 and FB100.name in out


def test_a_failed_model_in_models_does_not_shadow_the_shipped_one(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["train", "--fb", "100", "--steps", "1", "--n-data", "16", "--width", "4", "--depth",
                               "1", "--quiet"], capsys, monkeypatch)
    assert code == 0 and "not picked by default" in err
    trained = next((tmp_path / "models").glob("*.safetensors"))
    assert load_model(trained).failure is not None and load_model(trained).covers(Scene(fb=100))
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.2", str(tmp_path / "x.wav")], capsys, monkeypatch)
    assert code == 0 and f"({FB100})" in out, out + err
    code, out, _ = run_main(["models", "--long"], capsys, monkeypatch)
    line = next(x for x in out.splitlines() if trained.name in x)
    assert "FAILED" in line and "not picked by default" in line
    assert "FAILED" not in next(x for x in out.splitlines() if FB100.stem in x)
    # asked for by name it still renders, with a note that says what it is
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.05", "--model", str(trained), "--fallback", "fdm",
                               str(tmp_path / "z.wav")], capsys, monkeypatch)
    assert code == 0 and "is not validated" in out


def test_the_best_validated_covering_model_wins(tmp_path, monkeypatch):
    models = tmp_path / "models"
    models.mkdir()
    monkeypatch.chdir(tmp_path)
    rewrite(FB100, models / "worse.safetensors", lambda m: m["validation"].update(nmse=1e-3))
    sc = Scene(fb=100, duration=0.05)
    assert load_model(FB100).meta.validation["nmse"] < 1e-3
    assert render_operator(sc).info.model_path == str(FB100)  # the shipped model's lower NMSE beats 1e-3
    rewrite(FB100, models / "better.safetensors", lambda m: m["validation"].update(nmse=1e-9))
    assert render_operator(sc).info.model_path == str(models / "better.safetensors")
    rewrite(FB100, models / "broken.safetensors", lambda m: m["validation"].update(nmse=None, error="diverged"))
    rewrite(FB100, models / "poor.safetensors", lambda m: m["validation"].update(nmse=0.5))
    rewrite(FB100, models / "nan.safetensors", lambda m: m["validation"].update(nmse=float("nan")))
    assert render_operator(sc).info.model_path == str(models / "better.safetensors")
    failed = [m for m in available_models() if m.failure]
    here = models.resolve()
    assert {m.path.name for m in failed if m.path.parent.resolve() == here} == {"broken.safetensors",
                                                                                "poor.safetensors", "nan.safetensors"}
    # a failed model is never the default render's
    assert render_operator(sc).info.model_path not in {str(m.path) for m in failed}


def test_a_render_reads_the_model_directories_once_and_the_next_render_sees_a_new_file(tmp_path, monkeypatch):
    # a note's render asked for the listing four times (its pick, its windows' pick, the renderer's, the skipped
    # files' notes): once now, and a file that appears after it is the next render's pick
    from bowsynth.api import render
    from bowsynth.engines.operator import choose

    models = tmp_path / "models"
    models.mkdir()
    monkeypatch.chdir(tmp_path)
    calls = []
    scan = choose._scan
    monkeypatch.setattr(choose, "_scan", lambda: calls.append(1) or scan())
    sc = Scene(fb=100, duration=0.05)
    assert render(sc, windows="free").info.model_path == str(FB100) and len(calls) == 1
    rewrite(FB100, models / "better.safetensors", lambda m: m["validation"].update(nmse=1e-9, lsd_db=1e-3))
    assert render(sc, windows="free").info.model_path == str(models / "better.safetensors") and len(calls) == 2
    choose.available_models()  # outside a render: read afresh
    assert len(calls) == 3


def test_point_models_of_one_bow_go_by_their_validation_nmse(tmp_path, monkeypatch):
    # a point model plays free windows, the windows its validation rolled: the lowest NMSE from rest is the truest
    # there (at the paper's F_B 1000 scene a point model at 1.9e-5 plays 0.017 dB and 0.002 cents off, one at 4.0e-4
    # 0.11 dB and 0.13 cents)
    from bowsynth.engines.operator.choose import find_model

    models = tmp_path / "models"
    models.mkdir()
    monkeypatch.chdir(tmp_path)
    sc = Scene(fb=100, duration=0.05)
    nmse = load_model(FB100).meta.validation["nmse"]
    rewrite(FB100, models / "worse.safetensors", lambda m: m["validation"].update(nmse=2 * nmse))
    assert find_model(sc).path == FB100
    rewrite(FB100, models / "better.safetensors", lambda m: m["validation"].update(nmse=nmse / 2))
    assert find_model(sc).path == models / "better.safetensors"
    # an edited record (text or null where a number belongs, digest recomputed) orders last, never breaks the pick
    for bad in ("x", None, float("nan")):
        rewrite(FB100, models / "odd.safetensors", lambda m: m["validation"].update(nmse=bad))
        assert find_model(sc).path == models / "better.safetensors"
    stick = Scene(f0=100.0, fb=1000.0, vb=0.2)
    pick = find_model(stick)
    points = [m for m in shipped_models() if m.failure is None and not m.domain.is_range and m.covers(stick)]
    assert len(points) > 1 and pick.meta.validation["nmse"] == min(m.meta.validation["nmse"] for m in points)
    assert pick.meta.validation["nmse"] < 1e-4


def test_the_narrowest_covering_box_wins_over_a_lower_validation_nmse():
    """Validation NMSE comes from each box's own bows, so it does not compare across boxes: among models that cover a
    scene the one with the smallest box of bows plays it (a point model before any box), then the lowest NMSE."""
    import copy
    import dataclasses

    from bowsynth.engines.operator.choose import covering_model

    base = load_model(soft_bow_model().path)

    def variant(box, nmse):
        m = copy.copy(base)
        m.meta = copy.deepcopy(base.meta)
        m.meta.domain = dataclasses.replace(base.domain, box=list(box))
        m.meta.validation["nmse"] = nmse
        return m

    soft = variant([0.015, 0.4, 0.05, 0.3], 0.05)
    wide = variant([0.01, 0.45, 0.0, 0.3], 1e-3)
    narrow = variant([0.1, 0.2, 0.1, 0.2], 0.05)
    sc = Scene(fb=0.15 * 2 * np.pi * 100, vb=0.15, duration=0.1)
    assert wide.domain.bow_extent > soft.domain.bow_extent > narrow.domain.bow_extent > 0
    assert covering_model(sc, [wide, soft]) is soft and covering_model(sc, [soft, wide]) is soft
    assert covering_model(sc, [wide, soft, narrow]) is narrow
    # outside the narrow box the next narrowest that covers plays; a bow stop only the wide box covers
    assert covering_model(sc.replace(vb=0.25), [wide, soft, narrow]) is soft
    assert covering_model(sc.replace(vb=0.02), [wide, soft, narrow]) is wide
    fb100 = load_model(FB100)
    assert fb100.domain.bow_extent == 0 and covering_model(Scene(fb=100), [wide, soft, fb100]) is fb100


def test_a_bow_at_the_edge_of_the_narrowest_box_goes_to_a_model_that_has_it_deeper():
    """Range models are weakest at their edges: a scene within EDGE of the narrow box's edge, and deeper in another
    covering box, is played by the other; where every box has it at an edge, the narrowest again."""
    import copy
    import dataclasses

    from bowsynth.engines.operator.choose import EDGE, covering_model

    base = load_model(soft_bow_model().path)

    def variant(box):
        m = copy.copy(base)
        m.meta = copy.deepcopy(base.meta)
        m.meta.domain = dataclasses.replace(base.domain, box=list(box))
        return m

    narrow, wide = variant([0.1, 0.2, 0.1, 0.2]), variant([0.02, 0.4, 0.0, 0.3])
    at = lambda b, v: Scene(fb=b * 2 * np.pi * 100, vb=v, duration=0.1)  # noqa: E731
    assert covering_model(at(0.14, 0.15), [wide, narrow]) is narrow  # the middle of both
    edge_v = 0.1 + 0.5 * EDGE * 0.1  # half the margin inside the narrow box's v_B span
    assert narrow.domain.edge_depth((0.14, 0.14), (edge_v, edge_v)) < EDGE
    assert covering_model(at(0.14, edge_v), [wide, narrow]) is wide
    assert covering_model(at(0.1005, 0.15), [narrow, wide]) is wide  # at its F_B / w edge (log span)
    # a bow curve: its span's ends count
    sweep = Scene(fb=[(0.0, 0.12 * 2 * np.pi * 100), (0.1, 0.199 * 2 * np.pi * 100)], vb=0.15, duration=0.1)
    assert covering_model(sweep, [narrow, wide]) is wide
    # at the edge of both (wide's top v_B is 0.3; narrow does not cover it): the only cover; both at an edge: the one
    # that has the bow deeper, whatever its size (tight: 0.34 % of its v_B span; a bigger box 3.5 %)
    tight = variant([0.1, 0.2, 0.005, 0.3])
    assert covering_model(at(0.14, 0.299), [tight, wide]) is tight
    bigger = variant([0.02, 0.4, 0.0, 0.31])
    assert bigger.domain.edge_depth((0.14, 0.14), (0.299, 0.299)) < EDGE
    assert covering_model(at(0.14, 0.299), [tight, bigger]) is bigger
    mid = (0.02 * 0.4) ** 0.5  # the middle of its log F_B / w span, and of its v_B span
    assert wide.domain.edge_depth((mid, mid), (0.15, 0.15)) == pytest.approx(0.5)
    assert load_model(FB100).domain.edge_depth((0.159, 0.159), (0.2, 0.2)) == float("inf")


def test_a_pick_is_kept_per_bow_and_asked_afresh_when_a_model_is_revalidated_or_the_start_state_moves(monkeypatch):
    """A score asks for each note's model several times with a new Scene each time: the pick is kept by what decides
    it (the bows, the start state, the pitch's window), not by the Scene; a new validation or a start state outside
    the trained states asks the models again."""
    import copy
    import dataclasses

    from bowsynth.engines.operator.choose import covering_model

    base = load_model(soft_bow_model().path)

    def variant(box):
        m = copy.copy(base)
        m.__dict__.pop("_failure", None)
        m.meta = copy.deepcopy(base.meta)
        m.meta.domain = dataclasses.replace(base.domain, box=list(box))
        return m

    narrow, wide = variant([0.1, 0.2, 0.1, 0.2]), variant([0.02, 0.4, 0.0, 0.3])
    w = 2 * np.pi * 100
    assert covering_model(Scene(fb=0.14 * w, vb=0.15, duration=0.1), [narrow, wide]) is narrow

    def asked(self, scene):
        raise AssertionError("asked again")
    monkeypatch.setattr(OperatorModel, "covers", asked)
    assert covering_model(Scene(fb=0.14 * w, vb=0.15, duration=2.5), [narrow, wide]) is narrow  # kept
    with pytest.raises(AssertionError, match="asked again"):
        covering_model(Scene(fb=0.14 * w, vb=0.15, duration=0.1, q0=0.01), [narrow, wide])
    monkeypatch.undo()
    assert covering_model(Scene(fb=0.14 * w, vb=0.15, duration=0.1, q0=50.0, p0=50.0), [narrow, wide]) is None
    narrow.meta.validation = {**narrow.meta.validation, "error": "1 of 9 grid points failed"}  # as the trainer does
    assert covering_model(Scene(fb=0.14 * w, vb=0.15, duration=0.1), [narrow, wide]) is wide


def test_model_lookup_is_cached_until_a_file_changes(tmp_path, monkeypatch):
    models = tmp_path / "models"
    models.mkdir()
    monkeypatch.chdir(tmp_path)
    path = rewrite(FB100, models / "mine.safetensors", lambda m: m["validation"].update(nmse=1e-9))
    first = {m.path: m for m in available_models()}
    second = {m.path: m for m in available_models()}
    assert all(second[p] is first[p] for p in first) and len(first) >= 4
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # same size, newer: read again
    third = {m.path: m for m in available_models()}
    assert third[path] is not first[path] and third[FB100] is first[FB100]
    path.write_bytes(b"garbage")  # now unreadable: skipped by the lookup, listed as such by `models`
    assert path not in {m.path for m in available_models()}


@pytest.mark.parametrize("name", ["paper-fb10", "paper-fb100", "paper-fb1000", "rest-linear"])
def test_the_check_floor_binds_only_where_two_windows_carry_no_friction(name):
    """The physics check's normaliser is at least (CHECK_FLOOR c)^2: for the paper models the friction their first
    two windows carry is far above it (their check is unchanged); from rest at the slow onset of a point model with
    the rest-linearised flow (NetConfig.rest_linear: a slow bow that speaks late) it is 1e-7 of c^2 and the floor
    decides."""
    import math

    from bowsynth import physics
    from bowsynth.engines.operator.basis import numpy_operator
    from bowsynth.engines.operator.check import CHECK_FLOOR, CHECK_STEPS, CHECK_WINDOWS, reference_tau

    slow = name == "rest-linear"
    models = ([m for m in shipped_models() if not m.domain.is_range and m.cfg.rest_linear] if slow
              else [load_model(SHIPPED_DIR / f"{name}.safetensors")])
    assert models
    for m in models:
        op, d = numpy_operator(m), m.domain
        dtau, n = op.window / CHECK_STEPS, CHECK_WINDOWS * CHECK_STEPS
        rq, rp = reference_tau(0.0, 0.0, d.beta, d.vb, d.a, dtau, n)
        lq, lp = physics.linear_flow(0.0, 0.0, np.arange(n) * dtau)
        share = np.mean((rq - lq) ** 2 + (rp - lp) ** 2) / np.sum(op.corr_scale ** 2)
        if slow:
            assert share < CHECK_FLOOR ** 2 / 100 and check_physics(m) < 5e-3, m.path.stem
        else:
            assert share > 30 * CHECK_FLOOR ** 2
        assert math.isfinite(check_physics(m))


@pytest.mark.parametrize("args", [["render", "--pitch", "A4", "--fb", "276", "-d", "0.2", "x.wav"],
                                  ["score", "--score", "s.toml", "--mix", "m.wav"]], ids=["render-pitch", "score"])
def test_a_repeated_pitch_and_an_operator_score_load_no_torch(tmp_path, args):
    """The first `--pitch` measures the playing model's own sounding pitch (the operator, no reference); the same note
    again reads the on-disk table (bowsynth.io.cache). An operator score loads no torch and no numba from the first
    run on."""
    (tmp_path / "s.toml").write_text('[[voice]]\nname = "v"\nf0 = 120.0\nbeta = 0.159155\nduration = 0.2\n'
                                     '[[voice]]\nname = "w"\nf0 = 150.0\nbeta = 0.159155\nduration = 0.3\n')
    env = {**os.environ, "PYTHONPATH": str(ROOT), "BOWSYNTH_CACHE": str(tmp_path / "cache")}

    def modules():
        r = subprocess.run([sys.executable, "-X", "importtime", "-m", "bowsynth", *args], capture_output=True,
                           text=True, cwd=tmp_path, env=env, timeout=300)
        assert r.returncode == 0, r.stderr
        return {line.split("|")[-1].strip().split(".")[0] for line in r.stderr.splitlines() if "import time:" in line}

    first = modules()
    assert "numpy" in first and "numba" not in first and "torch" not in first
    again = modules()
    assert "numpy" in again and "numba" not in again and "torch" not in again
    if args[0] == "render":
        assert list((tmp_path / "cache" / "engine-ratio").rglob("*.json"))
        assert not (tmp_path / "cache" / "sounding-ratio").exists()  # the reference's solve never ran


def test_help_loads_no_numpy(tmp_path):
    """`bowsynth --help` (and a mistyped command) imports the CLI's own modules and typer only: numpy was 0.13 s of a
    0.45 s `--help` on this machine, pulled in by the `models` listing's formula at import."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-X", "importtime", "-m", "bowsynth", "--help"], capture_output=True,
                       text=True, cwd=tmp_path, env=env, timeout=120)
    assert r.returncode == 0 and "render" in r.stdout, r.stderr
    loaded = {line.split("|")[-1].strip().split(".")[0] for line in r.stderr.splitlines() if "import time:" in line}
    assert "bowsynth" in loaded and not loaded & {"numpy", "scipy", "torch", "soundfile"}, loaded


def noisy_branch(tensors, scale=0.06, seed=1):
    """Perturb the branch's weights: an honest model made less accurate (its metadata still true)."""
    rng = np.random.default_rng(seed)
    for k in tensors:
        if "branch" in k and "weight" in k:
            tensors[k] = (tensors[k] * (1 + scale * rng.standard_normal(tensors[k].shape))).astype(tensors[k].dtype)


def rewrite_weights(src, dst, edit):
    from safetensors import safe_open
    from safetensors.numpy import save_file

    with safe_open(str(src), framework="numpy") as f:
        meta = json.loads(f.metadata()["bowsynth"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    edit(tensors)
    meta["digest"] = digest(meta, tensors)
    save_file(tensors, str(dst), metadata={"bowsynth": json.dumps(meta)})
    return dst


def test_an_honest_but_inaccurate_model_is_told_from_a_mislabelled_one(tmp_path):
    """Over the check's limit, a model whose windows still fit its claimed bow best renders with a note (an inaccurate
    onset); one whose file claims a bow 10 % off is refused, naming the bow its weights fit as well."""
    from bowsynth.engines.operator.check import PHYSICS_MAX_ERROR

    honest = load_model(rewrite_weights(FB100, tmp_path / "noisy.safetensors", noisy_branch))
    assert check_physics(honest) > PHYSICS_MAX_ERROR
    r = render_operator(Scene(fb=100, duration=0.2), model=honest)
    assert any("not a mislabelled file" in n for n in r.info.notes)

    def claim_more_force(meta):
        meta["domain"]["beta"] *= 1.1
        meta["scene"]["fb"] *= 1.1

    liar = load_model(rewrite(FB100, tmp_path / "liar.safetensors", claim_more_force))
    assert check_physics(liar) > PHYSICS_MAX_ERROR
    with pytest.raises(ModelFileError, match="as well or better"):
        render_operator(Scene(fb=110, duration=0.2), model=liar)


def window_times_1e6(tensors):
    tensors["window"] = np.array(tensors["window"] * 1e6, dtype=np.float32)


def empty_mask(tensors):
    tensors["domain.mask"] = np.zeros((0, 0), np.uint8)


@pytest.mark.parametrize("damage", [window_times_1e6, empty_mask])
def test_a_damaged_model_in_models_is_skipped_and_breaks_no_other(tmp_path, monkeypatch, capsys, damage):
    """A file whose digest was recomputed over damaged tensors: refused at load in one line, and the default lookup
    in its directory still finds the shipped model (once, this hung for a minute or raised IndexError everywhere)."""
    models = tmp_path / "models"
    models.mkdir()
    bad = rewrite_weights(FB100, models / "damaged.safetensors", damage)
    with pytest.raises(ModelFileError, match="damaged"):
        load_model(bad)
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.1", str(tmp_path / "y.wav")], capsys, monkeypatch)
    assert code == 0 and FB100.name in out
    assert "skipped" in out and "damaged.safetensors" in out  # one line naming the file and why
    code, out, err = run_main(["render", "--fb", "100", "-d", "0.1", "--model", str(bad), str(tmp_path / "z.wav")],
                              capsys, monkeypatch)
    assert code != 0 and "damaged" in err and len(err.strip().splitlines()) == 1


from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st  # noqa: E402

_ODD = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30), st.none(),
                 st.text(max_size=5), st.lists(st.floats(-10, 10), max_size=5), st.booleans())


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(field=st.sampled_from(["beta", "vb", "a", "window", "q_lo", "q_hi", "p_lo", "p_hi", "box"]), value=_ODD)
@example(field="q_hi", value=2**64)  # found by a suite run: an int past int64 reached the compiled loop as objects
@example(field="p_lo", value=-10**400)  # past float64: float() overflows
def test_forged_domain_fields_load_cleanly_or_are_refused(tmp_path, field, value):
    """Any value in any domain field, digest recomputed: the model loads, or ModelFileError says why; a model that
    loads renders or refuses with a bowsynth error, fast (bounded work: no forged number makes the check loop)."""
    import time

    from bowsynth import BowsynthError

    def forge(meta):
        meta["domain"][field] = value

    try:
        path = rewrite(FB100, tmp_path / "f.safetensors", forge)
    except (ValueError, OverflowError):  # not JSON-encodable (e.g. NaN is, huge ints are): nothing to forge
        return
    t0 = time.perf_counter()
    try:
        m = load_model(path)
        render_operator(Scene(fb=100, duration=0.05), model=m)
    except BowsynthError:
        pass
    assert time.perf_counter() - t0 < 30


def test_range_models_are_judged_by_what_a_listener_hears():
    """A range model's verdict (picked by default or not) reads its validation grid's harmonic and pitch errors, not
    NMSE from rest; a point model is still judged by NMSE, and a failed grid point fails either."""
    from dataclasses import replace

    from bowsynth.engines.operator.modelfile import (MAX_VALIDATION_CENTS, MAX_VALIDATION_HARM_DB, is_finite,
                                                     validation_failure)

    meta = load_model(soft_bow_model().path).meta
    v = meta.validation
    assert validation_failure(meta) is None
    assert validation_failure(replace(meta, validation={**v, "nmse": 1.5})) is None  # phase, not sound
    loud_timbre = replace(meta, validation={**v, "harm_db_median": MAX_VALIDATION_HARM_DB * 1.5})
    assert "harmonics" in validation_failure(loud_timbre)
    assert "pitch" in validation_failure(replace(meta, validation={**v, "cents_abs_max": MAX_VALIDATION_CENTS + 1}))
    assert "failed" in validation_failure(replace(meta, validation={**v, "error": "1 of 9 grid points failed"}))
    point = load_model(FB100).meta
    off = replace(point, validation={**point.validation, "nmse": 0.5})
    assert validation_failure(off).startswith("validation NMSE")
    # the validated shipped range model with the highest NMSE from rest: over 0.1 (a phase; the stick-slip tiles
    # reach 1.1 and more), its sound within the limits, so it plays by default
    passed = [m for m in shipped_models() if m.domain.is_range and m.failure is None]
    loud = max(passed, key=lambda m: m.meta.validation["nmse"] if is_finite(m.meta.validation.get("nmse")) else 0)
    assert loud.meta.validation["nmse"] > 0.1 and validation_failure(loud.meta) is None


def test_a_range_model_must_rest_where_the_truth_rests_and_a_grid_that_all_rests_passes_by_that():
    """Where the bow damps the mass the truth rests, and a model that hums there plays a wrong note: such a grid bow
    fails the validation ('silent_sounding'). A box where every grid bow rests (the heavy bow stops at the space's
    edge) has no pitch or NMSE to score: it passes if the model rests at each. The selection scores a resting truth
    by the render's RMS in units of the silence threshold."""
    from dataclasses import replace

    from bowsynth.metrics import SILENT
    from bowsynth.engines.operator.modelfile import validation_failure
    from bowsynth.training.selection import listener_score

    meta = load_model(soft_bow_model().path).meta
    v = meta.validation
    assert "rest" in validation_failure(replace(meta, validation={**v, "silent_sounding": 1}))
    assert validation_failure(replace(meta, validation={**v, "silent_sounding": 0})) is None
    resting = [{"beta": 2.0, "vb": x, "speaks": False, "truth_sounds": False, "op_sounds": False} for x in (0, 0.04)]
    silent_box = {"points": resting, "grid": 2, "seconds": 1.0, "ref_oversample": 100, "speaking": 0,
                  "resting": 2, "silent_sounding": 0}
    assert validation_failure(replace(meta, validation=silent_box)) is None
    assert "rest" in validation_failure(replace(meta, validation={**silent_box, "silent_sounding": 2}))
    assert validation_failure(replace(meta, validation={k: x for k, x in silent_box.items()
                                                        if k != "silent_sounding"})) == "no validation score"
    t = np.arange(44100) / 44100
    rest, hum = np.zeros_like(t), 1e-3 * np.sin(2 * np.pi * 55 * t)
    assert listener_score(rest, rest, 44100) == 0.0
    assert listener_score(hum, rest, 44100) == pytest.approx(1e-3 / np.sqrt(2) / SILENT, rel=1e-3)


def test_a_stick_slip_tile_is_told_from_a_mislabelled_file_over_a_longer_span():
    # the tile the renderer picks for a loud middle-C note (F_B / w 0.55, v_B 0.244, just past the soft bow)
    from bowsynth.engines.operator.check import NEIGHBOURS, PHYSICS_MAX_ERROR, claim_fits_best, physics_error

    note = Scene(f0=261.63, fb=0.55 * 2 * np.pi * 261.63, vb=0.244, duration=0.5)
    m = shipped_pick(note)
    d = m.domain
    assert d.is_range
    err = physics_error(m, 0.0, 0.0)
    assert err > PHYSICS_MAX_ERROR  # its onset from rest is inaccurate...
    # ...and over the first two windows a bow 10 % away fits as well: that span alone would call the file a lie
    assert min(physics_error(m, 0.0, 0.0, d.beta * fb, d.vb * fv) for fb, fv in NEIGHBOURS) < 2 * err
    honest, _, _ = claim_fits_best(m, err)
    assert honest
    r = render_operator(note)
    assert r.info.model_path == str(m.path) and any("not a mislabelled file" in n for n in r.info.notes)


def test_a_tile_that_catches_the_stick_early_is_judged_by_its_limit_cycle(tmp_path):
    """The tile the renderer picks for a fast heavy bow (F_B / w 2, v_B 0.28: the corner, notes at a third of f0)
    catches the stick phase a quarter period early from rest: its first windows are off the physics, and sample by
    sample over 16 periods a bow 5 % slower fits it better than its claim, which would call an honest file a lie. Its
    limit cycle, shifted, fits the claim and no neighbour, so the corner plays; the same weights labelled as a weaker
    tile (F_B / w 20 % lower, its box moved with it) are refused."""
    from bowsynth.engines.operator.basis import numpy_operator
    from bowsynth.engines.operator.check import LONG_CHECK_PERIODS, NEIGHBOURS, PHYSICS_MAX_ERROR, claim_fits_best, \
        physics_error

    note = Scene(f0=110.0, fb=2.0 * 2 * np.pi * 110.0, vb=0.28, duration=0.3)
    m = shipped_pick(note)
    path, d = m.path, m.domain
    err = physics_error(m, 0.0, 0.0)
    assert err > PHYSICS_MAX_ERROR
    long = int(np.ceil(LONG_CHECK_PERIODS * 2 * np.pi / numpy_operator(m).window - 1e-9))
    plain = [physics_error(m, 0.0, 0.0, d.beta * fb, d.vb * fv, long) for fb, fv in ((1.0, 1.0), *NEIGHBOURS)]
    assert min(plain[1:]) < plain[0]
    assert claim_fits_best(m, err)[0]
    r = render_operator(note)
    assert r.info.model_path == str(path) and np.all(np.isfinite(r.p))

    def weaker(meta):
        dom = meta["domain"]
        dom["beta"], dom["box"][0], dom["box"][1] = 0.8 * dom["beta"], 0.8 * dom["box"][0], 0.8 * dom["box"][1]
        meta["scene"]["fb"] *= 0.8
    lie = rewrite(path, tmp_path / "lie.safetensors", weaker)
    # refused by the physics or, where the moved box leaves the bows its inputs were scaled to, at load
    with pytest.raises(ModelFileError, match="does not do what it claims|claims more than its weights"):
        render_operator(Scene(f0=110.0, fb=1.6 * 2 * np.pi * 110.0, vb=0.28, duration=0.3), model=lie)


# a fast bow past the soft bow (F_B / w 0.6, v_B 0.28): the renderer plays it on a tile of quarter-period windows
FAST_NOTE = Scene(f0=220.0, fb=0.6 * 2 * np.pi * 220.0, vb=0.28, duration=0.3)


def test_a_quarter_window_tile_is_told_from_a_mislabelled_file_over_16_periods():
    """The tile FAST_NOTE plays on has an onset from rest that sticks to the bow, whatever the force: over 16 of its
    quarter-period windows (4 periods) a bow 10 % away fits about as well as its claim, which would call the file a
    lie and refuse it; over 16 periods the claim fits best, and the note plays, with a note on its onset."""
    from bowsynth.engines.operator.basis import numpy_operator
    from bowsynth.engines.operator.check import NEIGHBOURS, PHYSICS_MAX_ERROR, claim_fits_best, physics_error

    m = shipped_pick(FAST_NOTE)
    d = m.domain
    assert numpy_operator(m).window == pytest.approx(np.pi / 2)
    err = physics_error(m, 0.0, 0.0)
    assert err > PHYSICS_MAX_ERROR
    near = min(physics_error(m, 0.0, 0.0, d.beta * fb, d.vb * fv, 16) for fb, fv in NEIGHBOURS)
    assert near < 2 * physics_error(m, 0.0, 0.0, windows=16)
    assert claim_fits_best(m, err)[0]
    r = render_operator(FAST_NOTE)
    assert r.info.model_path == str(m.path) and any("not a mislabelled file" in n for n in r.info.notes)


def test_a_files_physics_verdict_is_kept_by_its_digest_and_an_edited_file_is_checked_afresh(tmp_path, monkeypatch):
    """The neighbours of FAST_NOTE's tile over 16 periods cost 0.13 s a process: the verdict is kept on disk by the
    file's digest, so a later process (a new model object, the table read again) plays the note without checking; the
    same file with its metadata edited and the digest forged is checked again."""
    import shutil

    import bowsynth.engines.operator.check as check

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(check, "_verdicts", None)
    src = shutil.copy(shipped_pick(FAST_NOTE).path, tmp_path / "fast.safetensors")
    scene = FAST_NOTE
    first = render_operator(scene, model=load_model(src))
    assert any("not a mislabelled file" in n for n in first.info.notes)
    kept = {doc["key"]: doc["value"] for doc in
            (json.loads(p.read_text()) for p in (tmp_path / "cache" / "physics-check").rglob("*.json"))}
    key = load_model(src).meta.digest
    assert kept[f"claim {key}"][0] is True and kept[f"error {key}"] > PHYSICS_MAX_ERROR

    def no_check(*args, **kwargs):
        raise AssertionError("checked again")
    monkeypatch.setattr(check, "physics_error", no_check)
    monkeypatch.setattr(check, "_verdicts", None)  # as a new process: the table read from disk
    again = render_operator(scene, model=load_model(src))
    assert again.info.notes == first.info.notes and np.array_equal(again.p, first.p)
    forged = load_model(rewrite(src, tmp_path / "liar.safetensors", claim_double_force))
    assert forged.meta.digest != key
    with pytest.raises(AssertionError, match="checked again"):
        check_physics(forged)


def test_only_a_box_that_starts_in_the_soft_bow_plays_the_bows_below_it():
    # the soft bow's model (bottom F_B / w 0.01) plays an attack from F_B 0; a box that does not play below it (one
    # whose bottom lies at the soft / stick-slip boundary, 0.42, learned stick-slip states) does not claim F_B / w
    # 0.02-0.4: if it did, it would win those bows as the smaller box and leave its trained states within 0.06-0.42 s
    # (`bench map`: a row of unplayed cells at v_B 0.24)
    soft = soft_bow_model()
    shipped = [m for m in shipped_models() if m.failure is None]
    above = [m for m in shipped if m.domain.is_range and not m.domain.plays_below]
    assert soft.domain.plays_below and any(0.4 < m.domain.box[0] < 0.45 for m in above)
    weak = Scene(f0=110.0, fb=0.1 * 2 * np.pi * 110.0, vb=0.24, duration=0.5)
    assert soft.covers(weak) and not any(m.covers(weak) for m in above)
    # a soft box plays it (the soft bow's model, or a smaller one refined from it)
    assert load_model(render_operator(weak).info.model_path).domain.plays_below
    attack = Scene(f0=100.0, fb=[[0.0, 0.0], [0.05, 0.2 * 2 * np.pi * 100.0]], vb=0.2, duration=0.3)
    # a soft box plays it: the smallest that covers it (each has it at its bottom edge)
    r = render_operator(attack)
    assert soft.covers(attack) and not any(m.covers(attack) for m in above)
    pick = load_model(r.info.model_path)
    assert pick.domain.plays_below and pick.path != soft.path
    assert pick.domain.bow_extent == min(m.domain.bow_extent for m in shipped if m.covers(attack))


def domain_of_kind(kind):
    """The domain of a shipped model of each kind: the soft bow's range model, the first range model (by name) that
    does not play below its box, the first point model."""
    if kind == "soft range":
        return soft_bow_model().domain
    if kind == "range":
        return next(m for m in shipped_models() if m.domain.is_range and not m.domain.plays_below).domain
    return next(m for m in shipped_models() if not m.domain.is_range).domain


@pytest.mark.parametrize("kind", ["soft range", "range", "point"])
def test_one_state_is_in_the_domain_exactly_when_the_vectorised_test_says_so(kind):
    # Domain.contains takes a fast path for one state in plain floats (a score asks it ~1100 times): the same rule,
    # on random states around the box, its edges and a NaN
    d = domain_of_kind(kind)
    rng = np.random.default_rng(3)
    q = rng.uniform(d.q_lo - 0.1, d.q_hi + 0.1, 5000)
    p = rng.uniform(d.p_lo - 0.1, d.p_hi + 0.1, 5000)
    q[:3], p[3:6], q[6], p[7] = d.q_lo, d.p_hi, np.nan, np.nan
    many = d.contains(q, p)
    assert 0 < many.sum() < len(q)
    assert [d.contains(float(a), float(b)) for a, b in zip(q, p)] == many.tolist()


def test_a_voice_that_leaves_the_picked_models_states_is_played_by_the_next_covering_model(tmp_path, monkeypatch):
    """A tile (a narrower box of bows, so picked first) that has not learnt the states a bow near its edge reaches:
    the voice is played again by the next model that covers it, whole, and says so; asked for by name the tile still
    stops the render (or hands the rest to the FDM)."""
    from bowsynth import DomainError
    from bowsynth.engines.operator.engine import render_operator_batch

    from bowsynth.engines.operator.choose import covering_model

    soft = soft_bow_model().path

    def tile(meta):  # a smaller box of bows, and trained states a third of the note's swing
        meta["domain"]["box"] = [0.06, 0.18, 0.12, 0.24]
        meta["domain"].update(q_lo=-0.1, q_hi=0.1, p_lo=-0.1, p_hi=0.1)
    models = tmp_path / "models"
    models.mkdir()
    monkeypatch.chdir(tmp_path)
    rewrite(soft, models / "tile.safetensors", tile)
    sc = Scene(fb=0.1 * 2 * np.pi * 220, f0=220, vb=0.2, duration=0.3)
    outside = Scene(fb=0.3 * 2 * np.pi * 220, f0=220, vb=0.2, duration=0.3)  # outside the tile
    shipped = shipped_models()
    nxt = covering_model(sc, shipped).path  # what plays it without the tile
    assert covering_model(sc).path == models / "tile.safetensors"
    r = render_operator(sc)
    assert r.info.model_path == str(nxt) and r.method.engine == "operator" and not r.method.fdm_fallback
    assert any("tile: the rollout left the model's trained states" in n and f"played by {nxt.stem}" in n
               for n in r.info.notes), r.info.notes
    np.testing.assert_array_equal(r.p, render_operator(sc, model=nxt).p)
    # in a batch: the voice keeps its number and its place; the other voice is untouched
    a, b = render_operator_batch([outside, sc])
    assert b.info.model_path == str(nxt) and any(n.startswith("note: voice 2: tile:") for n in b.info.notes)
    np.testing.assert_array_equal(b.p, r.p)
    np.testing.assert_array_equal(a.p, render_operator(outside, model=covering_model(outside, shipped)).p)
    # a glide (pitch curve, beta held): the per-window loop hands over the same way
    pts = [(0.0, 220.0), (0.3, 233.0)]
    glide = Scene(f0=pts, fb=[(t, 0.1 * 2 * np.pi * f) for t, f in pts], vb=0.2, duration=0.3)
    g = render_operator(glide)
    assert g.info.model_path == str(nxt) and not g.method.fdm_fallback
    assert any("tile: the rollout left" in n and f"played by {nxt.stem}" in n for n in g.info.notes), g.info.notes
    np.testing.assert_array_equal(g.p, render_operator(glide, model=nxt).p)
    assert render_operator(glide, model=models / "tile.safetensors").method.fdm_fallback
    with pytest.raises(DomainError, match="left the model's trained states"):
        render_operator(sc, model=models / "tile.safetensors")
    assert render_operator(sc, model=models / "tile.safetensors", fallback="fdm").method.fdm_fallback


def test_the_live_instrument_keeps_the_largest_box_among_those_covering_the_most_velocities():
    """A smaller box trained for the velocities covers MIDI velocities 1-109 as the soft bow's model does, with a
    lower validation NMSE; the live default is still the soft bow's model, whose box keeps a note whose CC2 / CC11
    moved its bow on the operator."""
    from bowsynth.engines.operator.grid import needs_whole_windows
    from bowsynth.live.tables import Tuning
    from bowsynth.music import midi

    def velocities(m):  # those it plays live at neutral controllers (a stick-slip bow plays none: Stream._plays)
        return {v for v in range(1, 128) if m.domain.box_contains(midi.bow_beta(v), midi.bow_vb(v))
                and not needs_whole_windows(m.domain, midi.bow_beta(v))}

    shipped = shipped_models()
    soft = soft_bow_model()
    assert velocities(soft) == set(range(1, 110))
    tied = [m for m in shipped if m.failure is None and m is not soft and velocities(m) == velocities(soft)
            and m.meta.validation["nmse"] < soft.meta.validation["nmse"]]
    assert tied
    for order in (shipped, shipped[::-1]):
        assert Tuning.default_model(order, 100.0) is soft
    for vel in tied:
        assert vel.domain.bow_extent < soft.domain.bow_extent and Tuning.default_model([vel], 100.0) is vel


def test_a_listed_shipped_file_is_looked_up_by_its_header_and_its_weights_checked_when_played(tmp_path, monkeypatch):
    """A file the build listed in the manifest (name, size, digest) is read from its header alone; its weights are
    hashed when a render reads them. One whose weights were edited after the build (its metadata's digest kept, its
    size the same) is refused by name then; an unlisted file with the same edit is refused at once."""
    from bowsynth.engines.operator import manifest, modelfile
    from bowsynth.training.manifest import write_manifest

    shipped = tmp_path / "models"
    shipped.mkdir()
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(manifest, "MANIFEST", shipped / "MANIFEST.json")
    manifest._listed.cache_clear()
    good = shipped / "good.safetensors"
    good.write_bytes(FB100.read_bytes())
    edited = shipped / "edited.safetensors"
    edited.write_bytes(FB100.read_bytes())
    write_manifest(shipped)
    data = bytearray(edited.read_bytes())
    data[-8] ^= 0x01  # one bit of the last tensor's bytes: size and metadata unchanged
    edited.write_bytes(bytes(data))
    try:
        assert np.array_equal(load_model(good).weights["branch.U.weight"], load_model(FB100).weights["branch.U.weight"])
        m = load_model(edited)  # listed: its header is all a lookup reads
        assert m.meta.digest == load_model(FB100).meta.digest
        with pytest.raises(ModelFileError, match="edited after the build"):
            m.weights
        monkeypatch.setattr(manifest, "MANIFEST", tmp_path / "elsewhere" / "MANIFEST.json")
        with pytest.raises(ModelFileError, match="digest mismatch"):
            load_model(edited)
    finally:
        manifest._listed.cache_clear()
    assert modelfile.in_manifest is manifest.in_manifest


def test_the_manifest_lists_every_shipped_model_as_it_is():
    """The shipped manifest names each shipped file with its size and digest: a retrained or edited model is stale
    against it until `make models` writes it again."""
    from bowsynth.engines.operator import manifest

    listed = json.loads(manifest.MANIFEST.read_text())["models"]
    files = sorted(SHIPPED_DIR.glob("*.safetensors"))
    assert sorted(listed) == [p.name for p in files]
    for p in files:
        assert listed[p.name]["size"] == p.stat().st_size
        assert manifest.in_manifest(p, p.stat().st_size, load_model(p).meta.digest)



def test_a_box_or_state_range_past_what_the_weights_were_trained_for_is_refused(tmp_path):
    """A forger widens a range model's box (or any model's range of states) and recomputes the digest: the network's
    input scalings (pcenter / pscale, center / halfrange) say which bows and states it was trained on, and the file is
    refused in one line naming the claim. A narrower box, as a refinement claims, still loads and plays."""
    src = soft_bow_model().path

    def widen_box(meta):
        b = meta["domain"]["box"]
        meta["domain"]["box"] = [b[0], b[1] * 3.0, b[2], b[3]]

    def narrow_box(meta):
        b = meta["domain"]["box"]
        meta["domain"]["box"] = [b[0], b[0] + (b[1] - b[0]) / 2, b[2], b[3]]

    def widen_states(meta):
        meta["domain"]["q_lo"] *= 2.0
        meta["domain"]["q_hi"] *= 2.0

    for forge, what in ((widen_box, "its box"), (widen_states, "its range of q")):
        with pytest.raises(ModelFileError, match=f"claims more than its weights were trained for: {what}") as e:
            load_model(rewrite(src, tmp_path / f"{forge.__name__}.safetensors", forge))
        assert "\n" not in str(e.value)
    with pytest.raises(ModelFileError, match="its range of p"):
        load_model(rewrite(FB100, tmp_path / "point.safetensors",
                           lambda meta: meta["domain"].update(p_hi=meta["domain"]["p_hi"] + 5.0)))
    m = load_model(rewrite(src, tmp_path / "narrow.safetensors", narrow_box))
    b = m.domain.box
    sc = Scene(f0=100.0, fb=(b[0] + b[1]) / 2 * 2 * math.pi * 100.0, vb=(b[2] + b[3]) / 2, duration=0.2)
    assert np.std(render_operator(sc, model=m).p) > 0


def test_every_shipped_model_claims_only_what_its_weights_were_trained_for():
    from bowsynth.engines.operator.claims import claims_error

    for m in shipped_models():
        assert claims_error(m.domain, m.cfg, m.weights) is None, m.path.name
