"""Benchmarks: wall time per second of audio against error, for the FDM and the operators."""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import numpy as np

from ..engines.fdm import fdm_batch, render_fdm
from ..scene import Scene
from .metrics import nmse


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
# the paper's rollouts: the full files where this project's checkout keeps them (../shared/anchors beside the
# repository), else the reduced copies a clone carries for its tests (tests/data, see its README)
_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_ANCHORS = next((d for d in (_ROOT.parent / "shared" / "anchors", _ROOT / "tests" / "data") if d.is_dir()),
                       _ROOT.parent / "shared" / "anchors")


def _score(r, ref) -> dict:
    """NMSE(p) over the whole render and over its first 0.1 s and 0.5 s (the paper's spans), with the
    phase-insensitive measures beside it: pitch (cents, on q), harmonic amplitudes and log-spectral distance (on p)."""
    from .metrics import compare_signals, nmse

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


# --- out of sample -----------------------------------------------------------------------------------------------
#
# Training sees the band of states a render from the scene's initial state visits (with noise), and takes the exact
# window-start states of that render; the validation and the weight selection roll out that same trajectory. These
# cases start from states training never took exactly, or sample the windows at other offsets.

def band_states(model, n: int, rng: np.random.Generator, away: float = 0.25) -> np.ndarray:
    """n states drawn uniformly over the cells of the model's domain mask (the band, with its margin), each at least
    `away` times the band's half-size from rest (0, 0): a note that starts from a moving mass."""
    d = model.domain
    g = d.mask.shape[0]
    cells = np.argwhere(d.mask)
    half = 0.5 * min(d.q_hi - d.q_lo, d.p_hi - d.p_lo)
    out = np.empty((0, 2))
    while len(out) < n:
        c = cells[rng.integers(len(cells), size=4 * n)] + rng.random((4 * n, 2))
        x = np.stack([d.q_lo + c[:, 0] / g * (d.q_hi - d.q_lo), d.p_lo + c[:, 1] / g * (d.p_hi - d.p_lo)], 1)
        x = x[d.contains(x[:, 0], x[:, 1]) & (np.hypot(x[:, 0], x[:, 1]) > away * half)]
        out = np.concatenate([out, x])
    return out[:n]


def fractional_starts(scene: Scene, window: float, periods=(2, 20), fractions=(0.25, 0.5, 0.75)) -> np.ndarray:
    """States of the render from rest (FDM x100) at t = (m + f) T: on the trained trajectory, but where no window of
    that render starts (its windows start at whole multiples of T), in the onset (m = 2) and on the limit cycle."""
    t_win = window / scene.omega
    t_max = (max(periods) + 1) * t_win
    ref = render_fdm(scene.replace(duration=t_max, sample_rate=scene.sample_rate * 4, q0=0.0, p0=0.0),
                     oversample=REF_OVERSAMPLE // 4)
    idx = [int(round((m + f) * t_win * ref.scene.sample_rate)) for m in periods for f in fractions]
    return np.stack([ref.q[idx], ref.p[idx]], 1)


def _one_case(model, scene: Scene) -> dict:
    from ..engines.operator.engine import render_operator
    from ..errors import DomainError

    ref = render_fdm(scene, oversample=REF_OVERSAMPLE)
    try:
        r = render_operator(scene, model=model)
    except DomainError as e:
        return {"failed": str(e)}
    return _score(r, ref)


def _summary(label: str, scores: list[dict], detail: str) -> dict:
    ok = [s for s in scores if "failed" not in s]
    med = lambda k: float(np.median([s[k] for s in ok])) if ok else math.nan  # noqa: E731
    return {"case": label, "detail": detail, "n": len(scores), "failed": len(scores) - len(ok),
            "nmse_p_median": med("nmse_p"), "nmse_p_worst": max((s["nmse_p"] for s in ok), default=math.nan),
            "cents_worst": max((abs(s["cents"]) for s in ok), default=math.nan), "harmonic_db_median": med("harmonic_db"),
            "lsd_db_median": med("lsd_db")}


def bench_out_of_sample(model, duration: float = 1.0, n_states: int = 8, seed: int = 0) -> list[dict]:
    """Renders of `model` from initial states and at sample offsets training never used, each against an FDM x100 of
    the same scene; the first row is the in-sample render from rest at the model's own scene, for scale."""
    sc = Scene(**{**model.meta.scene, "duration": duration})
    rng = np.random.default_rng(seed)
    rows = [_summary("in sample: from rest, own scene", [_one_case(model, sc)], f"f0 {sc.f0:g}, {sc.sample_rate} Hz")]
    x = band_states(model, n_states, rng)
    rows.append(_summary("random band states, away from rest", [_one_case(model, sc.replace(q0=q, p0=p)) for q, p in x],
                         f"{n_states} states, seed {seed}"))
    x = fractional_starts(sc, model.domain.window)
    rows.append(_summary("rest trajectory at (m + f) T", [_one_case(model, sc.replace(q0=q, p0=p)) for q, p in x],
                         "m 2, 20; f 0.25, 0.5, 0.75"))
    for rate in (48_000, 96_000):
        s = sc.replace(sample_rate=rate)
        x0 = band_states(model, 2, rng)
        rows.append(_summary(f"{rate // 1000} kHz", [_one_case(model, s)] +
                             [_one_case(model, s.replace(q0=q, p0=p)) for q, p in x0], "from rest + 2 band states"))
    cases = []
    for f0 in (130.0, 200.0):  # T / dtau = 339.2 and 220.5 samples at 44.1 kHz: windows of two lengths
        s = sc.replace(f0=f0, fb=model.domain.beta * 2 * math.pi * f0)
        cases += [_one_case(model, s)] + [_one_case(model, s.replace(q0=q, p0=p)) for q, p in band_states(model, 1, rng)]
    rows.append(_summary("other pitches, T / dtau not whole", cases, "f0 130, 200 (same F_B / w): rest + 1 band state"))
    return rows


def window_errors(model, x0: np.ndarray, scene: Scene) -> np.ndarray:
    """NMSE(p) of the operator's one-window prediction from each state against an FDM x100 over the same window."""
    from ..engines.operator.rollout import rollout_states

    dtau = scene.dtau
    n = int(math.floor(model.domain.window / dtau)) + 1  # the window's samples and the next window's first
    _, p, _ = rollout_states(model, x0, n, dtau, check_domain=False)
    out = []
    for i, (q0, p0) in enumerate(x0):
        ref = render_fdm(scene.replace(q0=float(q0), p0=float(p0), duration=n / scene.sample_rate),
                         oversample=REF_OVERSAMPLE)
        out.append(nmse(p[i], ref.p))
    return np.array(out)


def band_distance(model, x: np.ndarray, scene: Scene) -> np.ndarray:
    """Distance of each state from the band (the audio-rate FDM's states over 1 s from the scene's initial state),
    as a fraction of the domain's box (each axis scaled by the box's side)."""
    d = model.domain
    r = render_fdm(scene.replace(duration=1.0))
    band = np.stack([r.q, r.p], 1)
    side = np.array([d.q_hi - d.q_lo, d.p_hi - d.p_lo])
    return np.array([np.hypot(*((band - xi) / side).T).min() for xi in np.asarray(x, float)])


NEAR = 0.025  # of the box: the training sampler's noise is 2.5 % of the band's range (sd); the mask reaches ~6 %


def bench_windows(model, n_states: int = 64, seed: int = 1) -> list[dict]:
    """One-window errors at the window starts of the render from rest (the states training took exactly) and at
    held-out band states (drawn over the domain's mask, not on that trajectory), split by their distance from the
    band: training draws its states near the band, while the domain's mask, which a render is allowed to visit,
    reaches farther."""
    sc = Scene(**model.meta.scene)
    n_win = int(math.floor(model.domain.window / sc.dtau))
    path = render_fdm(sc.replace(duration=1.0), oversample=REF_OVERSAMPLE)
    starts = np.stack([path.q[::n_win], path.p[::n_win]], 1)[:n_states]
    held = band_states(model, n_states, np.random.default_rng(seed), away=0.0)
    dist = band_distance(model, held, sc)
    rows = []
    for label, x0 in (("window starts of the render from rest (trained)", starts),
                      (f"held-out band states within {NEAR:.1%} of the box from the band", held[dist < NEAR]),
                      (f"held-out band states farther (the mask's margin)", held[dist >= NEAR])):
        if len(x0) == 0:
            continue
        e = window_errors(model, x0, sc)
        rows.append({"states": label, "n": len(e), "nmse_p_median": float(np.median(e)), "nmse_p_worst": float(e.max())})
    return rows


def bench_parameter_points(model, pitches=(100.0,), n: int = 4, duration: float = 1.0) -> list[dict] | None:
    """Held-out bows of a range model: the n x n grid of cell centres of its box (log beta; its training bows are a
    Latin hypercube of another seed) at each pitch, `duration` s from rest, operator against the FDM x100: NMSE(p) and
    the pitch error where the note speaks (training.ranges.speaks), quiet and finite where it does not. None for a
    point model (one bow: nothing to hold out)."""
    if not model.domain.is_range:
        return None
    from ..engines.operator.engine import render_operator
    from ..training.ranges import ParamBox, speaks
    from .metrics import cents, f0_estimate

    b0, b1, v0, v1 = model.domain.box
    box = ParamBox(b0, b1, v0, v1, model.domain.a)
    rows = []
    for f0 in pitches:
        for beta, vb in box.grid(n):
            sc = Scene(f0=f0, fb=float(beta) * 2 * math.pi * f0, vb=float(vb), a=box.a, duration=duration)
            ref = render_fdm(sc, oversample=REF_OVERSAMPLE)
            r = render_operator(sc, model=model, fallback="fdm")
            row = {"f0": f0, "beta": float(beta), "vb": float(vb), "speaks": bool(speaks(beta, vb, box.a, f0, duration)),
                   "method": r.method, "finite": bool(np.isfinite(r.p).all()),
                   "max_abs_p": float(np.max(np.abs(r.p))), "ref_max_abs_p": float(np.max(np.abs(ref.p)))}
            if row["speaks"]:
                row["nmse"] = float(nmse(r.p, ref.p))
                row["cents"] = float(cents(f0_estimate(r.q, sc.sample_rate), f0_estimate(ref.q, sc.sample_rate)))
            rows.append(row)
    return rows


def parameter_summary(rows: list[dict]) -> dict:
    """Median and worst NMSE(p) and worst |cents| over the speaking bows; the silent ones all finite?"""
    spk = [r for r in rows if r["speaks"]]
    vals = np.array([r["nmse"] for r in spk])
    return {"points": len(rows), "speaking": len(spk),
            "median_nmse": float(np.median(vals)) if len(vals) else None,
            "worst_nmse": float(np.max(vals)) if len(vals) else None,
            "worst_cents": float(np.max(np.abs([r["cents"] for r in spk]))) if spk else None,
            "quiet_all_finite": all(r["finite"] for r in rows if not r["speaks"]),
            "fdm_fallbacks": sum(r["method"] != "operator" for r in rows)}


def plot_pareto(rows, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.audio import atomic_write

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


def _g(v, fmt="{:.2e}") -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def speed_table(rows) -> str:
    dur = rows[0]["scene"].duration if rows else 1.0
    lines = [f"| scene | method | wall s per audio s | real-time factor | NMSE(p) {dur:g} s | pitch error (cents) | "
             "harmonic amplitudes (dB) | log-spectral distance (dB) | Pareto |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        sc = r["scene"]
        lines.append(f"| fb {sc.fb:g}, f0 {sc.f0:g} | {r['method']} | {r['sec_per_audio_s']:.2e} | "
                     f"{1 / r['sec_per_audio_s']:.0f}x | {r['nmse_p']:.2e} | {_g(r['cents'], '{:+.3f}')} | "
                     f"{_g(r.get('harmonic_db'), '{:.3f}')} | {_g(r.get('lsd_db'), '{:.2f}')} | "
                     f"{'yes' if r['pareto'] else ''} |")
    return "\n".join(lines)


def spans_table(rows) -> str:
    """NMSE(p) over the paper's spans (0-0.1 s, 0-0.5 s) and the whole render, for the operators and the audio-rate
    FDM at the presets' own pitch (f0 100)."""
    lines = ["| scene | method | NMSE(p) 0-0.1 s | NMSE(p) 0-0.5 s | NMSE(p) whole render |", "|---|---|---|---|---|"]
    for r in rows:
        sc = r["scene"]
        if sc.f0 != 100 or not (r["method"].startswith("operator") or r["method"] == "FDM x1"):
            continue
        lines.append(f"| fb {sc.fb:g}, {sc.duration:g} s | {r['method']} | {_g(r.get('nmse_p_0-0.1s'))} | "
                     f"{_g(r.get('nmse_p_0-0.5s'))} | {r['nmse_p']:.2e} |")
    return "\n".join(lines)


def out_of_sample_tables(oos: list[dict]) -> str:
    parts = ["| model | case | detail | renders (left the domain) | NMSE(p) median | NMSE(p) worst | worst / in sample | "
             "worst pitch error (cents) | harmonic amplitudes (dB), median | log-spectral distance (dB), median |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for o in oos:
        base = o["renders"][0]["nmse_p_worst"]
        for r in o["renders"]:
            ratio = r["nmse_p_worst"] / base if base and math.isfinite(r["nmse_p_worst"]) else math.nan
            parts.append(f"| {o['model'].removesuffix('.safetensors')} | {r['case']} | {r['detail']} | "
                         f"{r['n']} ({r['failed']}) | {_g(r['nmse_p_median'])} | {_g(r['nmse_p_worst'])} | "
                         f"{_g(ratio, '{:.1f}x')} | {_g(r['cents_worst'], '{:.3f}')} | "
                         f"{_g(r['harmonic_db_median'], '{:.3f}')} | {_g(r['lsd_db_median'], '{:.2f}')} |")
    parts += ["", "One window (the operator's prediction over one window from a state, against an FDM x100 from the "
              "same state; NMSE(p) per window):", "",
              "| model | states | n | NMSE(p) median | NMSE(p) worst |", "|---|---|---|---|---|"]
    for o in oos:
        for w in o["windows"]:
            parts.append(f"| {o['model'].removesuffix('.safetensors')} | {w['states']} | {w['n']} | "
                         f"{w['nmse_p_median']:.2e} | {w['nmse_p_worst']:.2e} |")
    points = [o for o in oos if o["parameter_points"] is not None]
    if not points:
        parts += ["", "Held-out parameter points: none (every model is a point model: one F_B / w, v_B and a)."]
    for o in points:
        sm = parameter_summary(o["parameter_points"])
        parts += ["", f"Held-out bows of {o['model']} (grid of its box, f0 100, from rest vs FDM x100): "
                      f"{sm['speaking']} of {sm['points']} speak, median NMSE(p) {_fmt(sm['median_nmse'])}, worst "
                      f"{_fmt(sm['worst_nmse'])}, worst pitch error {_fmt(sm['worst_cents'], '.3f')} cents; silent "
                      f"ones finite: {sm['quiet_all_finite']}; FDM fallbacks: {sm['fdm_fallbacks']}"]
    return "\n".join(parts)


def _fmt(v, fmt: str = ".2e") -> str:
    return "n/a" if v is None else format(v, fmt)


def run_all(quick: bool = False, out_prefix=None, anchor_dir=None) -> dict:
    """The full benchmark: FDM speed, speed against error per preset, batched voices, the paper's anchors."""
    from ..engines.operator.choose import available_models
    from ..music.request import make_scene

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
        result["paper_anchors_dir"] = str(anchor_dir)
    result["out_of_sample"] = []
    for m in models:
        if not m.covers(Scene(**m.meta.scene)):
            continue
        result["out_of_sample"].append({
            "model": m.path.name if m.path else m.meta.name,
            "renders": bench_out_of_sample(m, duration=dur, n_states=3 if quick else 8),
            "windows": bench_windows(m, n_states=16 if quick else 64),
            "parameter_points": bench_parameter_points(m, n=2 if quick else 4, duration=dur)})
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
    parts += ["", "### NMSE(p) over the paper's spans", spans_table(result["speed_error"])]
    if result.get("out_of_sample"):
        parts += ["", "### Out of sample", "Renders from initial states and at sample offsets training never used, "
                  f"each against an FDM x{REF_OVERSAMPLE} of the same scene; the first row of each model is the render "
                  "from rest at its own scene (in sample).", "", out_of_sample_tables(result["out_of_sample"])]
    if result.get("paper_anchors"):
        where = "/".join(Path(result.get("paper_anchors_dir", "anchors")).parts[-2:])
        parts += ["", f"### The paper's operators ({where}) against our FDM x{REF_OVERSAMPLE}",
                  "| case | NMSE(p) 0-0.1 s | NMSE(p) 0-0.5 s | NCC(p) 0-0.5 s (%) |", "|---|---|---|---|"]
        for r in result["paper_anchors"]:
            parts.append(f"| {r['case']} | {r['nmse_p_0.1s']:.2e} | {r['nmse_p_0.5s']:.2e} | {r['ncc_p_0.5s']:.2f} |")
    return "\n".join(parts)
