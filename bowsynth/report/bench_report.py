"""The benchmark as a report: it runs the measurements of bowsynth.analysis and writes them as Markdown tables, a
Pareto plot and JSON."""

from __future__ import annotations

import math
from pathlib import Path

from ..analysis.bench import bench_batch, bench_fdm, bench_paper_anchors, bench_scene, blas_gmacs, equal_accuracy
from ..analysis.out_of_sample import bench_out_of_sample, bench_parameter_points, bench_windows, parameter_summary
from ..engines.fdm import TRUTH_OVERSAMPLE
from ..scene import Scene
from ..io.text import jsonable, num


def fdm_table(rows: list[dict]) -> str:
    lines = ["| case | audio per voice (s) | wall (s) | real-time factor (all voices) | state-steps / s |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['audio_s']:g} | {r['wall_s']:.4f} | {r['realtime_factor']:.1f}x "
                     f"| {r['steps_per_s']:.3g} |")
    return "\n".join(lines)


# the paper's rollouts: the full files where this project's checkout keeps them (../shared/anchors beside the
# repository), else the reduced copies a clone carries for its tests (tests/data, see its README)
ANCHOR_DIRS = ("shared/anchors", "../shared/anchors", "tests/data")


def default_anchors() -> Path | None:
    """The paper's rollouts where a checkout of this project keeps them, relative to the current directory: the full
    files (shared/anchors beside the repository) or the reduced copies a clone carries for its tests (tests/data).
    An installed package has no such place: then None, and the anchors are skipped."""
    return next((Path(d) for d in ANCHOR_DIRS if Path(d).is_dir()), None)


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
        ax.set_ylabel(f"NMSE(p) vs FDM x{TRUTH_OVERSAMPLE}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)


def run_equal(quick: bool = False, out_prefix=None, windows: str | None = None, models=None, workers: int = 1,
              address: str | None = None) -> dict:
    """Speed at equal accuracy for every shipped model family at 100, 440 and 880 Hz (quick: one model at 100 Hz,
    FDM x1 and x2), with the machine's matrix-product speed measured in the same run; the operator in these windows
    (api.render's; None its default). models: these instead (paths or names). workers / address: a model a task
    (`io.cluster.Pool`: Ray, or processes), its rows back in the models' order; each task times its own renders,
    so tasks that share a machine share its memory and caches while they time."""
    from ..engines.operator.choose import SHIPPED_DIR, model_path, model_ref
    from ..io.cluster import Pool
    from ..music.engine_tuning import check_windows

    windows = check_windows(windows)
    paths = [model_path(m) for m in models] if models else sorted(SHIPPED_DIR.glob("*.safetensors"))
    if quick and not models:
        paths = [p for p in paths if p.stem == "paper-fb100"][:1]
    kw = dict(f0s=(100.0,), duration=1.0, repeats=1, oversamples=(1, 2)) if quick else {}
    jobs = [(model_ref(p), windows, kw) for p in paths]  # a shipped model by name: a cluster's node has its own
    with Pool(workers, address) as pool:
        done = dict(pool.map(_equal_task, jobs))
    rows = [r for i in range(len(jobs)) for r in done[i]]
    res = {"equal_accuracy": rows, "blas_gmac_per_s": blas_gmacs(), "windows": windows}
    if out_prefix and any("failed" not in r for r in rows):
        plot_equal(rows, f"{out_prefix}.png")
    return res


def _equal_task(job) -> list[dict]:
    """A task of run_equal: one model's rows."""
    from ..engines.operator.choose import as_model

    model, windows, kw = job
    return equal_accuracy(as_model(model), windows=windows, **kw)


def equal_table(res: dict) -> str:
    """One row per model and pitch: what the operator costs and how accurate it is, and the cheapest FDM as accurate
    on harmonics, pitch and NMSE at once."""
    peak = res["blas_gmac_per_s"]
    lines = [f"Errors against an FDM x{TRUTH_OVERSAMPLE}, {res['equal_accuracy'][0]['scene'].duration:g} s from rest "
             f"at the model's own bow (a range model's box centre), the operator in {res.get('windows', 'free')} "
             "windows; costs are wall seconds per audio second (warm, median). One core's float32 matrix product "
             f"(numpy's BLAS, one thread) in this run: {peak:.1f} GMAC/s.", "",
             "| model | f0 (Hz) | operator: harmonics dB / cents / NMSE(p) | operator s per s | GMAC/s (of the "
             "matrix product) | FDM as accurate | its s per s | speed-up at equal accuracy |",
             "|---|---|---|---|---|---|---|---|"] if res["equal_accuracy"] else ["(no model plays these pitches)"]
    for r in res["equal_accuracy"]:
        if "failed" in r:
            lines.append(f"| {r['model']} | {r['f0']:g} | not played: {r['failed']} | | | | | |")
            continue
        op = r["operator"]
        fdm = f"x{r['equal_oversample']}" if r["equal_oversample"] else f"none up to x{r['fdm'][-1]['oversample']}"
        cost = next((e["sec_per_audio_s"] for e in r["fdm"] if e["oversample"] == r["equal_oversample"]),
                    r["fdm"][-1]["sec_per_audio_s"])
        lines.append(f"| {r['model']} | {r['f0']:g} | {_g(op['harm_db'], '{:.3f}')} / {_g(op['cents'], '{:.3f}')} / "
                     f"{_g(op['nmse'])} | {op['sec_per_audio_s']:.2e} | {op['gmac_per_s']:.2f} "
                     f"({_g(op['gmac_per_s'] / peak, '{:.0%}')}) | {fdm} | {cost:.2e} | "
                     f"{'>= ' if r['ratio_is_bound'] else ''}{r['ratio']:.1f}x |")
    return "\n".join(lines)


def plot_equal(rows, path) -> None:
    """Error against cost, one panel per model: the FDM's oversamplings as a line per pitch, the operator as a dot
    of the same colour; harmonics (dB) on top, NMSE(p) below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.audio import atomic_write

    rows = [r for r in rows if "failed" not in r]
    models = list(dict.fromkeys(r["model"] for r in rows))
    fig, axes = plt.subplots(2, len(models), figsize=(4.2 * len(models), 7), squeeze=False)
    for j, name in enumerate(models):
        for i, (key, label) in enumerate((("harm_db", "harmonics, median error (dB)"), ("nmse", "NMSE(p)"))):
            ax = axes[i, j]
            for r, colour in zip([r for r in rows if r["model"] == name], ("tab:blue", "tab:orange", "tab:green")):
                xs = [e["sec_per_audio_s"] for e in r["fdm"]]
                ax.loglog(xs, [max(e[key], 1e-12) for e in r["fdm"]], "s-", color=colour, ms=4,
                          label=f"FDM x1..x{r['fdm'][-1]['oversample']}, {r['f0']:g} Hz")
                ax.loglog(r["operator"]["sec_per_audio_s"], max(r["operator"][key], 1e-12), "o", color=colour, ms=9,
                          mec="k", label=f"operator, {r['f0']:g} Hz")
            ax.set_title(name if i == 0 else "")
            ax.set_xlabel("wall seconds per second of audio")
            ax.set_ylabel(label)
            ax.grid(True, which="both", alpha=0.3)
            if j == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=80, format="png"))
    plt.close(fig)


def _g(v, fmt="{:.2e}") -> str:
    return num(v, fmt)


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
    return num(v, fmt)


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
    def scenes(v):
        if isinstance(v, Scene):
            return v.to_dict()
        if isinstance(v, dict):
            return {k: scenes(x) for k, x in v.items()}
        return [scenes(x) for x in v] if isinstance(v, list) else v

    return jsonable(scenes(result))


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
                  f"each against an FDM x{TRUTH_OVERSAMPLE} of the same scene; the first row of each model is the render "
                  "from rest at its own scene (in sample).", "", out_of_sample_tables(result["out_of_sample"])]
    if result.get("paper_anchors"):
        where = "/".join(Path(result.get("paper_anchors_dir", "anchors")).parts[-2:])
        parts += ["", f"### The paper's operators ({where}) against our FDM x{TRUTH_OVERSAMPLE}",
                  "| case | NMSE(p) 0-0.1 s | NMSE(p) 0-0.5 s | NCC(p) 0-0.5 s (%) |", "|---|---|---|---|"]
        for r in result["paper_anchors"]:
            parts.append(f"| {r['case']} | {r['nmse_p_0.1s']:.2e} | {r['nmse_p_0.5s']:.2e} | {r['ncc_p_0.5s']:.2f} |")
    return "\n".join(parts)
