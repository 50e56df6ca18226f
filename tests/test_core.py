"""The compiled core (bowsynth._core) at its edges: the arrays it refuses, a module that does not belong to the
package, a build without a compiler; and its loops against the numpy reference at window lengths that exercise every
tile of its products."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bowsynth import compiled as core
from bowsynth.engines.operator.choose import SHIPPED_DIR
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.rollout import rollout_states

from conftest import soft_bow_model

ROOT = Path(__file__).resolve().parents[1]
FB100 = SHIPPED_DIR / "paper-fb100.safetensors"


def loop_args(monkeypatch, voices=2):
    """The arguments rollout_states hands the compiled loop, captured from a real call."""
    seen = {}
    monkeypatch.setattr(core, "roll", lambda batch, *args: seen.setdefault("args", args))
    rollout_states(load_model(FB100), np.zeros((voices, 2)), 500, [0.02] * voices)
    monkeypatch.undo()
    return list(seen["args"])  # the last: rows, voice b's row of the outputs


NAMES = ["x0", "n_samples", "spw", "n_lo", "vidx", "Bq", "Bp", "endb", "endlin", "center", "halfrange", "ff", "pin",
         "gain", "Gw", "Gb", "Hw", "Hb", "Ow", "Ob", "box", "mask", "check", "q_out", "p_out", "fail", "rows"]


@pytest.mark.parametrize("kernel", ["roll_voices", "roll_batch"])
def test_the_loops_refuse_wrong_dtypes_ranks_and_shapes_with_one_error(monkeypatch, kernel):
    args = loop_args(monkeypatch)
    fn = getattr(core.load(), kernel)
    fn(*args)  # as given: runs
    arrays = [i for i, a in enumerate(args) if isinstance(a, np.ndarray)]
    for i in arrays:
        name, a = NAMES[i], args[i]
        other = np.float32 if a.dtype != np.float32 else np.float64
        for bad, err in [(a.astype(other), TypeError),  # a dtype it would have to convert (an output would be lost)
                         (a[..., None], TypeError),  # another rank
                         (np.asfortranarray(a) if a.ndim > 1 and min(a.shape) > 1 else None, TypeError)]:
            if bad is None:
                continue
            with pytest.raises(err):
                fn(*args[:i], bad, *args[i + 1:])
        if a.ndim and a.shape[-1] > 1 and name not in ("q_out", "p_out", "mask"):
            # one element short: named, or (an array that sets a size) the first array that no longer agrees
            with pytest.raises(ValueError, match=f"^{kernel}: "):
                fn(*args[:i], np.ascontiguousarray(a[..., :-1]), *args[i + 1:])
    ro = args[23].copy()
    ro.flags.writeable = False
    with pytest.raises(TypeError):  # an output it cannot write
        fn(*args[:23], ro, *args[24:])
    for i, value, what in [(1, 10**9, "q_out"), (4, np.array([0, 5]), "vidx"), (3, args[3] + 1, "n_lo"),
                           (2, np.array([0.5]), "spw"), (26, np.array([0, 2]), "rows"),
                           (26, np.array([-1, 0]), "rows")]:
        with pytest.raises(ValueError, match=what):
            fn(*args[:i], value, *args[i + 1:])


def test_the_fdm_refuses_bad_curves_and_short_outputs():
    c = core.load()
    t, v = np.zeros(1), np.ones(1)
    out = np.empty(10)
    c.fdm_run(0.0, 0.0, 0.0, 0, 10, 1, 1e-5, t, v * 4e5, t, v * 100.0, t, v * 0.2, 100.0, 1e-14, 60, out, out.copy())
    with pytest.raises(ValueError, match="hold n_out"):
        c.fdm_run(0.0, 0.0, 0.0, 0, 11, 1, 1e-5, t, v, t, v, t, v, 100.0, 1e-14, 60, out, out.copy())
    with pytest.raises(ValueError, match="times must increase"):
        c.fdm_run(0.0, 0.0, 0.0, 0, 10, 1, 1e-5, np.array([0.0, 0.0]), np.ones(2), t, v, t, v, 100.0, 1e-14, 60,
                  out, out.copy())
    with pytest.raises(ValueError, match="as many times as values"):
        c.fdm_run(0.0, 0.0, 0.0, 0, 10, 1, 1e-5, t, np.ones(2), t, v, t, v, 100.0, 1e-14, 60, out, out.copy())
    with pytest.raises(ValueError, match="positive"):
        c.fdm_run(0.0, 0.0, 0.0, 0, 10, 1, float("nan"), t, v, t, v, t, v, 100.0, 1e-14, 60, out, out.copy())
    with pytest.raises(TypeError):
        c.fdm_run(0.0, 0.0, 0.0, 0, 10, 1, 1e-5, t, v, t, v, t, v, 100.0, 1e-14, 60, out.astype(np.float32), out)


def test_the_dc_filter_refuses_what_it_cannot_filter_in_place():
    c = core.load()
    x = np.ones(8)
    c.highpass_zero_phase(x, 7e-4)
    assert np.max(np.abs(x)) < 1e-12  # a constant is steady state: nothing comes out
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="positive"):
            c.highpass_zero_phase(np.ones(8), bad)
    for arr in (np.ones(8, np.float32), np.ones((2, 4)), np.ones(16)[::2]):  # a copy would be filtered, not arr
        with pytest.raises(TypeError):
            c.highpass_zero_phase(arr, 7e-4)
    c.highpass_zero_phase(np.zeros(0), 7e-4)


def test_the_fdm_follows_a_w2_curve_like_the_numpy_scheme():
    """w^2 given per step as breakpoints (a pitch that moves): the compiled loop against the same scheme written out
    in numpy, step by step."""
    from bowsynth.engines.fdm import _solve_eta_bracketed
    from bowsynth.physics import NEWTON_MAXIT, NEWTON_TOL

    k, n, a, fb, vb = 1 / 44100, 3000, 100.0, 150.0, 0.2
    w2_t, w2_v = np.array([0.0, 0.05]), (2 * np.pi * np.array([100.0, 300.0])) ** 2
    u, eta = np.empty(n), np.empty(n)
    t1, v1 = np.zeros(1), np.ones(1)
    core.load().fdm_run(0.0, 0.0, -vb, 0, n, 1, k, w2_t, w2_v, t1, v1 * fb, t1, v1 * vb, a, NEWTON_TOL, NEWTON_MAXIT,
                        u, eta)
    up, uc, e = 0.0, 0.0, np.array([-vb])
    ref = np.empty(n)
    for j in range(n):
        w2 = np.interp(j * k, w2_t, w2_v)
        b = 2 / k * vb + 2 / k**2 * (up - uc) + w2 * uc
        e = _solve_eta_bracketed(e, np.array([b]), 2 / k, np.array([fb]), a)
        ref[j] = uc
        up, uc = uc, up + 2 * k * (e[0] + vb)
    assert np.abs(u - ref).max() <= 1e-12 * np.abs(ref).max() and np.abs(ref).max() > 0


@pytest.mark.parametrize("voices", [1, 9], ids=["voice-loop", "batch-loop"])
def test_every_window_length_matches_the_numpy_reference(voices):
    """Windows of 3 to 200 samples (pitches from ~1.4 kHz down to 100 Hz... and beyond the products' tiles: fewer than
    one vector, ragged ends of every width) against the numpy loop."""
    m = load_model(FB100)
    spw = np.array([3.0, 7.5, 8.0, 9.0, 15.0, 17.3, 23.0, 31.9, 40.0, 57.0, 63.0, 64.0, 65.0, 71.0, 121.0, 200.0])
    dtau = m.domain.window / spw
    rng = np.random.default_rng(0)
    for i in range(0, len(spw), voices):
        d = dtau[i:i + voices]
        if len(d) < voices:
            d = np.resize(dtau, voices)
        x0 = np.stack([rng.uniform(-0.05, 0.05, voices), rng.uniform(-0.05, 0.05, voices)], 1)
        qa, pa, fa = rollout_states(m, x0, 400, d, check_domain=False, loop="core")
        qb, pb, fb = rollout_states(m, x0, 400, d, check_domain=False, loop="numpy")
        assert np.array_equal(fa, fb)
        ok = np.isfinite(qb)
        assert np.array_equal(ok, np.isfinite(qa))
        assert np.abs(qa[ok] - qb[ok]).max() < 1e-5 and np.abs(pa[ok] - pb[ok]).max() < 1e-5


def test_a_stale_module_or_another_abi_is_refused_in_one_line(monkeypatch):
    monkeypatch.setattr(core, "_module", None)
    monkeypatch.setattr(core, "source_digest", lambda d: "0" * 64)
    with pytest.raises(core.CoreError, match="built from other sources.*stale build.*pip install -e") as e:
        core.load()
    assert "\n" not in str(e.value)
    monkeypatch.setattr(core, "ABI", core.ABI + 1)
    with pytest.raises(core.CoreError, match="has ABI .* expects .* stale build"):
        core.load()
    monkeypatch.undo()
    assert core.load().ABI == core.ABI


def test_the_digest_is_the_one_compiled_in():
    digest = core.source_digest(ROOT / "src" / "core")
    if digest is None:
        pytest.skip("no sources beside the package (an installed wheel)")
    assert core.load().DIGEST == digest


@pytest.mark.parametrize("broken", ["missing", "not-a-library"])
def test_a_module_that_does_not_load_is_one_line_from_the_cli(tmp_path, broken):
    """No module (not built, or built for another Python: its file name carries that interpreter's tag) or a file
    that is no library: `render` says so in one line and exits 1, never a crash."""
    pkg = tmp_path / "bowsynth"
    shutil.copytree(ROOT / "bowsynth", pkg, ignore=shutil.ignore_patterns("_core.*", "__pycache__"))
    if broken == "not-a-library":
        (pkg / Path(core.load().__file__).name).write_bytes(b"\x7fELF but not really")
    # -S: no .pth files, so an editable install's import redirect (scikit-build-core maps bowsynth._core to the
    # build it made) cannot hand the copy the real module; the site-packages stay on the path for numpy and the rest
    import site

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *site.getsitepackages()])}
    r = subprocess.run([sys.executable, "-S", "-m", "bowsynth", "render", "--method", "fdm", "-d", "0.1",
                        str(tmp_path / "x.wav")], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "compiled core" in lines[0] and "pip install -e ." in lines[0], r.stderr


def test_a_build_without_a_compiler_says_so_in_one_line(tmp_path):
    cmake, ninja = shutil.which("cmake"), shutil.which("ninja")
    if not (cmake and ninja):
        pytest.skip("cmake and ninja are needed to configure the build")
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    (bin_ / "ninja").symlink_to(ninja)  # a PATH with a build tool and no compiler
    r = subprocess.run([cmake, "-S", str(ROOT), "-B", str(tmp_path / "build"), "-G", "Ninja"], capture_output=True,
                       text=True, env={"PATH": str(bin_), "HOME": str(tmp_path)}, timeout=120)
    assert r.returncode != 0
    said = [line.strip() for line in r.stderr.splitlines() if "bowsynth:" in line]
    assert said == ["bowsynth: no C++ compiler found: install g++ (apt-get install g++)"], r.stderr


@pytest.mark.parametrize("kernel", ["roll_voices", "roll_batch"])
def test_the_loops_write_each_voice_into_its_row_and_leave_the_others(monkeypatch, kernel):
    args = loop_args(monkeypatch)
    args[0] = np.array([[0.0, 0.0], [1e-3, -2e-3]])  # two voices that sound different, both in the model's states
    fn = getattr(core.load(), kernel)
    fn(*args)
    q1, p1 = args[23].copy(), args[24].copy()
    assert (args[25][:, 0] == -1).all() and not np.array_equal(q1[0], q1[1])
    n = q1.shape[1]
    q, p = np.full((3, n), 7.0, np.float32), np.full((3, n), 7.0, np.float32)
    fail = np.array([[-1, 0], [9, 9], [-1, 0]], np.int64)  # the loops write only a voice that fails
    fn(*args[:23], q, p, fail, np.array([2, 0], np.int64))  # voice 0 into row 2, voice 1 into row 0
    np.testing.assert_array_equal(q[2], q1[0])
    np.testing.assert_array_equal(p[0], p1[1])
    np.testing.assert_array_equal(fail[[2, 0]], args[25])
    assert (q[1] == 7.0).all() and (p[1] == 7.0).all() and (fail[1] == 9).all()  # a row no voice names: untouched


def _cpu_runs_avx512() -> bool:
    try:
        flags = next(line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags"))
    except (OSError, StopIteration):
        return False
    return {"avx512f", "avx512vl", "avx512bw", "avx512dq"} <= set(flags.split(":", 1)[1].split())


def test_the_avx512_and_avx2_loops_play_alike(tmp_path):
    """Where the CPU runs AVX-512 (and on x86-64 with GCC, where it is built) the batch's products take 16 floats,
    unless BOWSYNTH_NO_AVX512 asks for the AVX2 loops. A batch of nine voices at nine window lengths in a process
    without them plays within float32 rounding of this process's (the test above holds this process's to the numpy
    reference)."""
    import platform

    built = core.load().AVX512_BUILT
    assert built or platform.machine() not in ("x86_64", "AMD64")  # this suite's machines build it with GCC
    assert core.load().vector_width() == (16 if built and _cpu_runs_avx512() else 8)
    m = load_model(FB100)
    spw = np.array([3.0, 9.0, 15.0, 17.3, 40.0, 65.0, 121.0, 200.0, 441.0])
    x0 = np.stack([np.linspace(-0.05, 0.05, 9), np.linspace(0.05, -0.05, 9)], 1)
    here = rollout_states(m, x0, 900, m.domain.window / spw, check_domain=False, loop="core-batch")
    script = (f"import numpy as np; from bowsynth import compiled as core; "
              f"from bowsynth.engines.operator.modelfile import load_model; "
              f"from bowsynth.engines.operator.rollout import rollout_states; m = load_model({str(FB100)!r}); "
              f"spw = np.array({spw.tolist()}); x0 = np.array({x0.tolist()}); "
              f"q, p, f = rollout_states(m, x0, 900, m.domain.window / spw, check_domain=False, loop='core-batch'); "
              f"np.savez({str(tmp_path / 'avx2.npz')!r}, q=q, p=p, f=f); print(core.load().vector_width())")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "BOWSYNTH_NO_AVX512": "1"})
    assert r.returncode == 0 and r.stdout.strip() == "8", r.stdout + r.stderr
    there = np.load(tmp_path / "avx2.npz")
    assert np.array_equal(there["f"], here[2]) and np.isfinite(here[0]).all()
    for a, b in ((here[0], there["q"]), (here[1], there["p"])):
        assert np.abs(a - b).max() < 1e-5 * max(1.0, np.abs(b).max())


# Every loop that runs one voice's branch a row at a time (one voice, the voice-after-voice loop, a batch's rows left
# over by fours, a live voice), for a width-128 range model (the file argv[2] names) and the width-64 paper model,
# into the .npz argv[1] names
_PANEL_PLAY = """
import sys, numpy as np
from bowsynth import compiled as core
from bowsynth.engines.operator.bank import VoiceBank
from bowsynth.engines.operator.choose import SHIPPED_DIR
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.rollout import rollout_states
out = {}
models = (("range", sys.argv[2], [0.15, 0.2]), ("paper-fb100", SHIPPED_DIR / "paper-fb100.safetensors", None))
for name, path, bow in models:
    m = load_model(path)
    kw = {} if bow is None else {"params": np.array(bow)}
    x0 = np.stack([np.linspace(-0.02, 0.02, 5), np.linspace(0.01, -0.01, 5)], 1)
    dtau = 2 * np.pi * np.array([880.0, 440.0, 311.1, 150.0, 100.0]) / 44100
    for loop, B in (("core-1", 1), ("core-voices", 3), ("core-batch", 5)):
        q, p, f = rollout_states(m, x0[:B], 3000, dtau[:B], check_domain=False, loop=loop, **kw)
        out[f"{name}-{loop}"] = np.stack([q, p])
    if bow is not None:
        b = VoiceBank(44100, 64, 1, "operator", m, 440.0)
        b.start_slot(0, 440.0, bow[0], bow[1], 100.0)
        b.bow_inputs(0, bow[0], bow[1])
        assert b.start_operator(0, 440.0)
        live = np.zeros(64 * 40)
        for i in range(40):
            b.render(live, 64 * i, 64, 1.0)
        out[f"{name}-live"] = live
np.savez(sys.argv[1], **out)
print(core.load().panels())
"""


def test_the_weights_in_panels_change_no_sample(tmp_path):
    """One voice's branch reads its weights in panels of 64 columns (src/core/rollout.cpp: pack_net), each panel's
    rows in a row: the products add in the same order, so every loop that uses them (one voice, voice after voice,
    a batch's rows left over by fours, a live voice) plays the same samples to the bit as the strided products a
    process with BOWSYNTH_NO_PANELS=1 runs, in the AVX-512 and the AVX2 loops."""
    soft = soft_bow_model()
    box = soft.domain.box  # the range model's bow (F_B / w 0.15, v_B 0.2) is inside it, its width two panels
    assert box[0] <= 0.15 <= box[1] and box[2] <= 0.2 <= box[3] and soft.cfg.width == 128, (soft.path, box)
    for extra in ({}, {"BOWSYNTH_NO_AVX512": "1"}):
        runs = {}
        for panels in ("0", "1"):
            f = tmp_path / f"{panels}{len(extra)}.npz"
            env = {**os.environ, **extra, "BOWSYNTH_NO_PANELS": "1" if panels == "0" else "0"}
            r = subprocess.run([sys.executable, "-c", _PANEL_PLAY, str(f), str(soft.path)], capture_output=True,
                               text=True, timeout=300, env=env)
            assert r.returncode == 0 and r.stdout.strip() == ("True" if panels == "1" else "False"), r.stderr
            runs[panels] = np.load(f)
        assert sorted(runs["1"].files) == sorted(runs["0"].files) and len(runs["1"].files) == 7
        for key in runs["1"].files:
            a, b = runs["1"][key], runs["0"][key]
            assert np.isfinite(a).all() and np.abs(a).max() > 1e-3, key  # the voices sound
            assert np.array_equal(a, b), key


def test_the_weights_and_bases_the_loops_read_start_on_64_byte_lines():
    """The compiled products load 8 or 16 floats along a weight row or a basis row: the operator's weights and every
    row of a stack of window bases start on a 64-byte line (basis.lined), so that no load straddles two lines
    (where the arrays fell 16 or 48 bytes past one, 64 voices ran 2688-3287x by the process, 3602-3955x on lines).
    The values are the model's."""
    from bowsynth.engines.operator.basis import window_bases, numpy_operator

    for path in (FB100, soft_bow_model().path):
        m = load_model(path)
        op = numpy_operator(m)
        assert all(a.ctypes.data % 64 == 0 and a.flags.c_contiguous and a.dtype == np.float32 for a in op.weights)
        assert np.array_equal(op.weights[-2], m.weights["branch.out.weight"].T)
        dt = [2 * np.pi * f / 44100 for f in (97.0, 440.0, 880.0)]
        spw, n_lo, Bq, Bp, endb, endlin = window_bases(m, [(d, None) for d in dt])
        assert Bq.shape[2] % 16 == 0 and Bq.shape[2] >= np.ceil(spw).max()
        for B in (Bq, Bp):
            assert B.ctypes.data % 64 == 0 and B.flags.c_contiguous
            assert not B[:, :, int(np.ceil(spw).max()) + 1:].any()  # the padding plays no part
