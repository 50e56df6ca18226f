"""Benchmarks: wall time per second of audio against error, for the FDM and the operators."""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from ..engines.fdm import TRUTH_OVERSAMPLE, fdm_batch, render_fdm
from ..scene import Scene
from ..metrics import EQUAL_OVERSAMPLES


def _median_time(fn, repeats: int) -> float:
    fn()  # warm: compile, caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_fdm(quick: bool = False) -> list[dict]:
    """Single-voice real-time factor at 44.1 kHz and 4.41 MHz, and batch throughput for 4096 initial states."""
    rows = []
    reps = 3 if quick else 7
    for label, dur, os_ in (("single voice, 44.1 kHz", 2.0 if quick else 10.0, 1),
                            ("single voice, 4.41 MHz (x100)", 0.05 if quick else 0.5, 100)):
        s = Scene(fb=100, duration=dur)
        sec = _median_time(lambda: render_fdm(s, oversample=os_), reps)
        rows.append({"case": label, "audio_s": dur, "wall_s": sec, "realtime_factor": dur / sec,
                     "steps_per_s": s.n_samples * os_ / sec})
    s = Scene(fb=100)
    rng = np.random.default_rng(0)
    n_states, n_steps = 4096, 441 if quick else 4410
    q0, p0 = rng.uniform(-0.2, 0.2, n_states), rng.uniform(-0.2, 0.2, n_states)
    sec = _median_time(lambda: fdm_batch(q0, p0, n_steps, 1, 1 / 44100, s.omega, s.fb, s.vb, s.a), 1 if quick else 3)
    rows.append({"case": f"batch, {n_states} states, 44.1 kHz", "audio_s": n_steps / 44100, "wall_s": sec,
                 "realtime_factor": n_states * n_steps / 44100 / sec, "steps_per_s": n_states * n_steps / sec})
    return rows


# --- speed against error -----------------------------------------------------------------------------------------


def score_render(r, ref) -> dict:
    """NMSE(p) over the whole render and over its first 0.1 s and 0.5 s (the paper's spans), with the
    phase-insensitive measures beside it: pitch (cents, on q), harmonic amplitudes and log-spectral distance (on p)."""
    from ..metrics import compare_signals, nmse

    sr = r.scene.sample_rate
    m = compare_signals(r.p, ref.p, sr, r.q, ref.q)
    out = {"nmse_p": m["nmse"], "cents": m["cents"], "harmonic_db": m["harmonic_error_db"], "lsd_db": m["lsd_db"]}
    for span in (0.1, 0.5):
        n = int(round(span * sr))
        if n < len(ref.p):
            out[f"nmse_p_0-{span:g}s"] = nmse(r.p[:n], ref.p[:n])
    return out


def bench_scene(scene: Scene, models, repeats: int, oversamples=(1, 2, 4, 8)) -> list[dict]:
    """Every method on one scene: FDM at each oversampling, and each operator that covers the scene."""
    from ..engines.operator.engine import render_operator

    ref = render_fdm(scene, oversample=TRUTH_OVERSAMPLE)
    rows = []
    for os_ in oversamples:
        r = render_fdm(scene, oversample=os_)
        sec = _median_time(lambda: render_fdm(scene, oversample=os_), repeats)
        rows.append({"scene": scene, "method": f"FDM x{os_}", "sec_per_audio_s": sec / scene.duration,
                     **score_render(r, ref)})
    for m in models:
        if not m.covers(scene):
            continue
        r = render_operator(scene, model=m)
        sec = _median_time(lambda: render_operator(scene, model=m), repeats)
        rows.append({"scene": scene, "method": f"operator {m.path.name if m.path else m.meta.name}",
                     "sec_per_audio_s": sec / scene.duration, "train_s": m.meta.training.get("seconds"),
                     **score_render(r, ref)})
    front = pareto(rows)
    for i, r in enumerate(rows):
        r["pareto"] = i in front
    return rows


def pareto(rows) -> set:
    """Indices of rows no other row beats on both time and error."""
    out = set()
    for i, a in enumerate(rows):
        if not any(b["sec_per_audio_s"] <= a["sec_per_audio_s"] and b["nmse_p"] <= a["nmse_p"]
                   and (b["sec_per_audio_s"], b["nmse_p"]) != (a["sec_per_audio_s"], a["nmse_p"])
                   for b in rows):
            out.add(i)
    return out


def bench_batch(model, n_voices: int, duration: float, repeats: int) -> dict:
    """Throughput of n voices in one batched operator rollout against n sequential FDM renders.

    The voices are a sweep of initial states along the model's band (the states of an FDM render from rest,
    so each voice starts at another point of the note): same pitch, one batch."""
    from ..engines.operator.engine import render_operator

    sc = Scene(**{**model.meta.scene, "duration": duration})
    path = render_fdm(sc.replace(duration=0.5))
    idx = np.linspace(0, len(path.q) - 1, n_voices).astype(int)
    scenes = [sc.replace(q0=float(path.q[i]), p0=float(path.p[i])) for i in idx]
    scenes = [s for s in scenes if model.covers(s)]
    t_op = _median_time(lambda: render_operator(scenes, model=model), repeats)
    t_fdm = _median_time(lambda: [render_fdm(s) for s in scenes], max(1, repeats // 2))
    audio = duration * len(scenes)
    return {"voices": len(scenes), "audio_s_per_voice": duration, "operator_batched_s": t_op, "fdm_sequential_s": t_fdm,
            "operator_rtf_aggregate": audio / t_op, "fdm_rtf_aggregate": audio / t_fdm, "speedup": t_fdm / t_op,
            "model": model.path.name if model.path else model.meta.name}


def bench_paper_anchors(anchor_dir) -> list[dict]:
    """The paper's own operator rollouts (shared/anchors) scored against our high-rate FDM over 0.1 and 0.5 s."""
    from ..metrics import ncc, nmse

    rows = []
    for fb, fname in ((10, "paper_deeponet_fb10"), (100, "paper_deeponet_fb100"), (1000, "paper_deeponet_fb1000"),
                      (1000, "paper_deeponet_hybrid_fb1000")):
        path = Path(anchor_dir) / f"{fname}.npz"
        if not path.is_file():
            continue
        d = np.load(path)
        n = len(d["p"])
        rate = int(round((n - 1) / 0.5))
        ref = render_fdm(Scene(fb=fb, sample_rate=rate, duration=n / rate), oversample=TRUTH_OVERSAMPLE)
        m01 = int(0.1 * rate) + 1
        rows.append({"case": fname, "nmse_p_0.1s": nmse(d["p"][:m01], ref.p[:m01]), "nmse_p_0.5s": nmse(d["p"], ref.p[:n]),
                     "ncc_p_0.5s": ncc(d["p"], ref.p[:n])})
    return rows


# --- speed at equal accuracy ---------------------------------------------------------------------------------------

EQUAL_F0 = (100.0, 440.0, 880.0)


def window_macs(model) -> int:
    """The operator's multiply-adds once a window: the branch network (its weight matrices, Fourier features
    included)."""
    from ..engines.operator.npnet import weight_shapes

    return sum(int(np.prod(shape)) for name, shape in weight_shapes(model.cfg).items()
               if name.startswith("branch.") and name.endswith(("weight", "ff.B")))


def sample_macs(model) -> int:
    """The operator's multiply-adds once a sample: the window's basis product, 2 (k + 3) (q and p)."""
    return 2 * (model.cfg.k + 3)


def macs_per_second(model, scene: Scene) -> float:
    """The operator's multiply-adds per second of audio at the scene's pitch: window_macs once a window, sample_macs
    once a sample."""
    from ..engines.operator.basis import numpy_operator

    windows = scene.sample_rate / numpy_operator(model).samples_per_window(scene.dtau)
    return window_macs(model) * windows + sample_macs(model) * scene.sample_rate


def blas_gmacs(n: int = 512, repeats: int = 10) -> float:
    """One core's float32 matrix-product speed now (numpy's BLAS held to one thread): the peak the operator's
    multiply-adds are measured against, since its loops run on one core. In a child process, because BLAS reads its
    thread count once, when numpy loads."""
    import os
    import subprocess
    import sys

    code = (f"import time, numpy as np\na = np.random.default_rng(0).standard_normal(({n}, {n})).astype(np.float32)\n"
            f"a @ a\nbest = 1e9\nfor _ in range({repeats}):\n    t = time.perf_counter(); a @ a; "
            f"best = min(best, time.perf_counter() - t)\nprint({n}**3 / best / 1e9)")
    one = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    r = subprocess.run([sys.executable, "-c", code], env={**os.environ, **one}, capture_output=True, text=True,
                       timeout=120)
    return float(r.stdout) if r.returncode == 0 else float("nan")


def equal_accuracy(model, f0s=EQUAL_F0, duration: float = 2.0, repeats: int = 3,
                   oversamples=EQUAL_OVERSAMPLES, windows: str | None = None) -> list[dict]:
    """The operator against the FDM at equal accuracy, at the model's own bow (a point model's; a range model's box
    centre) at each pitch: the operator's errors against a x100 FDM (metrics.accuracy: harmonics, pitch, NMSE) and
    its cost (wall seconds per audio second, warm, median), the FDM's at each oversampling, and the cheapest FDM as
    accurate on all three (metrics.as_accurate). A pitch the model cannot play is left out. windows: the operator's,
    as api.render's, None its default (a lock is measured once, before the timing: it is cached on disk as in a
    user's renders)."""
    from ..engines.fdm import check_oversample
    from ..engines.operator.engine import render_operator
    from ..errors import DomainError
    from ..music.engine_tuning import check_windows, sounding_for
    from ..metrics import accuracy, as_accurate

    windows = check_windows(windows)
    d, rows = model.domain, []
    name = model.path.stem if model.path else model.meta.name
    for f0 in f0s:
        sc = Scene(f0=f0, fb=d.beta * 2 * np.pi * f0, vb=d.vb, a=d.a, duration=duration)
        if not model.covers(sc):
            continue
        ref = render_fdm(sc, oversample=TRUTH_OVERSAMPLE).p
        try:
            lock = sounding_for(sc, windows, model)
            op = accuracy(render_operator(sc, model=model, sounding=lock).p, ref, sc.sample_rate)
        except DomainError as e:  # the rollout left the model's states: no accuracy to match
            rows.append({"model": name, "scene": sc, "f0": f0, "beta": d.beta, "vb": d.vb, "failed": str(e)})
            continue
        op["windows"] = windows if lock is not None else "free"
        op["sec_per_audio_s"] = _median_time(lambda: render_operator(sc, model=model, sounding=lock),
                                             repeats) / duration
        op["gmac_per_s"] = macs_per_second(model, sc) / op["sec_per_audio_s"] / 1e9
        fdm = []
        # an oversampling below the scene's stability bound is raised by the FDM: each is measured once, as itself
        for os_ in sorted({check_oversample(sc, o, warn=False) for o in oversamples}):
            e = accuracy(render_fdm(sc, oversample=os_).p, ref, sc.sample_rate)
            e["oversample"] = os_
            e["sec_per_audio_s"] = _median_time(lambda: render_fdm(sc, oversample=os_), repeats) / duration
            fdm.append(e)
        match = next((e for e in fdm if as_accurate(e, op)), None)
        rows.append({"model": name, "scene": sc, "f0": f0, "beta": d.beta, "vb": d.vb, "operator": op, "fdm": fdm,
                     "equal_oversample": match["oversample"] if match else None,
                     # no oversampling tried reaches the operator: the ratio is at least the costliest one's
                     "ratio": (match or fdm[-1])["sec_per_audio_s"] / op["sec_per_audio_s"],
                     "ratio_is_bound": match is None})
    return rows


# --- out of sample -----------------------------------------------------------------------------------------------
#
# Training sees the band of states a render from the scene's initial state visits (with noise), and takes the exact
# window-start states of that render; the validation and the weight selection roll out that same trajectory. These
# cases start from states training never took exactly, or sample the windows at other offsets.


