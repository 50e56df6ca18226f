"""Benchmarks: wall time per second of audio against error, for the FDM and the operators."""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import numpy as np

from .fdm import fdm_batch, render_fdm
from .scene import Scene


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


def fdm_table(rows: list[dict]) -> str:
    lines = ["| case | audio per voice (s) | wall (s) | real-time factor (all voices) | state-steps / s |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['audio_s']:g} | {r['wall_s']:.4f} | {r['realtime_factor']:.1f}x "
                     f"| {r['steps_per_s']:.3g} |")
    return "\n".join(lines)


# --- speed against error -----------------------------------------------------------------------------------------

REF_OVERSAMPLE = 100
# the paper's rollouts, where this project's checkout keeps them (../shared/anchors beside the repository)
DEFAULT_ANCHORS = Path(__file__).resolve().parents[2] / "shared" / "anchors"
PAPER = {  # the paper's operators over 0.5 s (shared/anchors/README.md): NMSE(p), training
    10: ("2.5e-4", "36.6 h GPU"), 100: ("9.5e-7", "21.4 h GPU"), 1000: ("2.81 (hybrid 1.72)", "14.2 h GPU"),
}


def _score(r, ref) -> dict:
    from .metrics import cents, f0_estimate, nmse

    return {"nmse_p": nmse(r.p, ref.p), "cents": cents(f0_estimate(r.q, r.scene.sample_rate),
                                                          f0_estimate(ref.q, ref.scene.sample_rate))}


def bench_scene(scene: Scene, models, repeats: int, oversamples=(1, 2, 4, 8)) -> list[dict]:
    """Every method on one scene: FDM at each oversampling, and each operator that covers the scene."""
    from .rollout import render_operator

    ref = render_fdm(scene, oversample=REF_OVERSAMPLE)
    rows = []
    for os_ in oversamples:
        r = render_fdm(scene, oversample=os_)
        sec = _median_time(lambda: render_fdm(scene, oversample=os_), repeats)
        rows.append({"scene": scene, "method": f"FDM x{os_}", "sec_per_audio_s": sec / scene.duration,
                     **_score(r, ref)})
    for m in models:
        if not m.covers(scene):
            continue
        r = render_operator(scene, model=m)
        sec = _median_time(lambda: render_operator(scene, model=m), repeats)
        rows.append({"scene": scene, "method": f"operator {m.path.name if m.path else m.meta.name}",
                     "sec_per_audio_s": sec / scene.duration, "train_s": m.meta.training.get("seconds"),
                     **_score(r, ref)})
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
    from .rollout import render_operator

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
    from .metrics import ncc, nmse

    rows = []
    for fb, fname in ((10, "paper_deeponet_fb10"), (100, "paper_deeponet_fb100"), (1000, "paper_deeponet_fb1000"),
                      (1000, "paper_deeponet_hybrid_fb1000")):
        path = Path(anchor_dir) / f"{fname}.npz"
        if not path.is_file():
            continue
        d = np.load(path)
        n = len(d["p"])
        rate = int(round((n - 1) / 0.5))
        ref = render_fdm(Scene(fb=fb, sample_rate=rate, duration=n / rate), oversample=REF_OVERSAMPLE)
        m01 = int(0.1 * rate) + 1
        rows.append({"case": fname, "nmse_p_0.1s": nmse(d["p"][:m01], ref.p[:m01]), "nmse_p_0.5s": nmse(d["p"], ref.p[:n]),
                     "ncc_p_0.5s": ncc(d["p"], ref.p[:n])})
    return rows


def plot_pareto(rows, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .wav import atomic_write

    scenes = []
    for r in rows:
        if r["scene"] not in scenes:
            scenes.append(r["scene"])
    ncol = min(3, len(scenes))
    nrow = math.ceil(len(scenes) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5 * ncol, 4.2 * nrow), squeeze=False)
    for ax in axes.flat[len(scenes):]:
        ax.set_visible(False)
    for ax, sc in zip(axes.flat, scenes):
        rs = [r for r in rows if r["scene"] == sc]
        for r in rs:
            op = r["method"].startswith("operator")
            ax.loglog(r["sec_per_audio_s"], max(r["nmse_p"], 1e-16), "o" if op else "s",
                      color="tab:red" if op else "tab:blue", ms=8)
            ax.annotate(r["method"].replace("operator ", "op ").removesuffix(".safetensors"),
                        (r["sec_per_audio_s"], max(r["nmse_p"], 1e-16)), fontsize=7, xytext=(4, 4),
                        textcoords="offset points")
        front = sorted([r for r in rs if r["pareto"]], key=lambda r: r["sec_per_audio_s"])
        ax.loglog([r["sec_per_audio_s"] for r in front], [max(r["nmse_p"], 1e-16) for r in front], "k--", lw=1,
                  label="Pareto front")
        ax.set_title(f"fb={sc.fb:g}, f0={sc.f0:g} Hz, {sc.duration:g} s")
        ax.set_xlabel("wall seconds per second of audio")
        ax.set_ylabel(f"NMSE(p) vs FDM x{REF_OVERSAMPLE}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)


def speed_table(rows) -> str:
    lines = ["| scene | method | wall s per audio s | real-time factor | NMSE(p) 1 s | pitch error (cents) | Pareto |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        sc = r["scene"]
        lines.append(f"| fb {sc.fb:g}, f0 {sc.f0:g} | {r['method']} | {r['sec_per_audio_s']:.2e} | "
                     f"{1 / r['sec_per_audio_s']:.0f}x | {r['nmse_p']:.2e} | {r['cents']:+.3f} | "
                     f"{'yes' if r['pareto'] else ''} |")
    return "\n".join(lines)


def run_all(quick: bool = False, out_prefix=None, anchor_dir=None) -> dict:
    """The full benchmark: FDM speed, speed against error per preset, batched voices, the paper's anchors."""
    from .rollout import available_models
    from .scene import make_scene

    models = [m for m in available_models()]
    repeats = 3 if quick else 7
    dur = 0.3 if quick else 1.0
    rows = []
    for name in ("paper-fb10", "paper-fb100", "paper-fb1000"):
        sc = make_scene(name, duration=dur)
        rows += bench_scene(sc, models, repeats, oversamples=(1, 4) if quick else (1, 2, 4, 8))
        # the same F_B / w at another pitch: one model serves it
        sc2 = sc.replace(f0=2 * sc.f0, fb=2 * sc.fb)
        if any(m.covers(sc2) for m in models) and not quick:
            rows += bench_scene(sc2, models, repeats, oversamples=(1, 8))
    result = {"fdm": bench_fdm(quick=quick), "speed_error": rows}
    batch_models = [m for m in models if m.covers(Scene(**{**m.meta.scene, "duration": 0.5}))]
    batch_models.sort(key=lambda m: m.path is None or m.path.stem != "paper-fb100")  # the paper's middle case first
    if batch_models:
        result["batch"] = [bench_batch(batch_models[0], n, 0.2 if quick else 1.0, 1 if quick else 3)
                           for n in ((16,) if quick else (8, 64, 256))]
    if anchor_dir and Path(anchor_dir).is_dir() and not quick:
        result["paper_anchors"] = bench_paper_anchors(anchor_dir)
    if out_prefix:
        plot_pareto(rows, f"{out_prefix}.png")
    return result


def to_json(result: dict) -> dict:
    def conv(v):
        if isinstance(v, Scene):
            return v.to_dict()
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        if isinstance(v, list):
            return [conv(x) for x in v]
        if isinstance(v, float) and not math.isfinite(v):
            return None
        return v

    return conv(result)


def to_markdown(result: dict) -> str:
    parts = ["### FDM speed", fdm_table(result["fdm"]), "", "### Speed against error (single voice, warm, median)",
             speed_table(result["speed_error"])]
    if result.get("batch"):
        parts += ["", "### Batched voices", f"Model {result['batch'][0]['model']}; the voices start at points along "
                  "the note's band (one batch each).", "", "| voices | operator, one batched rollout (s) | FDM, "
                  "sequential (s) | operator aggregate real-time | FDM aggregate real-time | speed-up |",
                  "|---|---|---|---|---|---|"]
        for b in result["batch"]:
            parts.append(f"| {b['voices']} x {b['audio_s_per_voice']:g} s | {b['operator_batched_s']:.4f} | "
                         f"{b['fdm_sequential_s']:.4f} | {b['operator_rtf_aggregate']:.0f}x | "
                         f"{b['fdm_rtf_aggregate']:.0f}x | {b['speedup']:.1f}x |")
    if result.get("paper_anchors"):
        parts += ["", f"### The paper's operators (shared/anchors) against our FDM x{REF_OVERSAMPLE}",
                  "| case | NMSE(p) 0-0.1 s | NMSE(p) 0-0.5 s | NCC(p) 0-0.5 s (%) |", "|---|---|---|---|"]
        for r in result["paper_anchors"]:
            parts.append(f"| {r['case']} | {r['nmse_p_0.1s']:.2e} | {r['nmse_p_0.5s']:.2e} | {r['ncc_p_0.5s']:.2f} |")
    return "\n".join(parts)
