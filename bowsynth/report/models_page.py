"""`bowsynth models --report M.html`: each model file found, what it carries (domain, training, selection,
validation) and, measured when the page is made, how it sounds against a x100 FDM: a point model at its own scene,
a range model on a grid of held-out bows over its box (a coloured map, with players for a few of them).

The measuring is the slow part: one x100 FDM per bow (about half a second for 1 s at f0 100 on this machine), so the
page for the shipped models takes tens of seconds at the default grid of 3 x 3."""

from __future__ import annotations

import math
import time
from datetime import datetime, timezone

import numpy as np

from ..engines.fdm import TRUTH_OVERSAMPLE
from ..engines.operator.modelfile import unpicked_text
from . import html as H
from . import listen as L

SECONDS = 1.0


def held_out_bows(domain, n: int) -> np.ndarray:
    """An n x n grid over the box (log F_B / w, v_B), offset by a quarter cell from the validation grid that
    training records (cell centres): bows neither training, selection nor validation used. (n*n, 2)."""
    b0, b1, v0, v1 = domain.box
    fb = (np.arange(n) + 0.75) / n
    fv = (np.arange(n) + 0.25) / n
    lo, hi = math.log(max(b0, 1e-12)), math.log(max(b1, 1e-12))
    bb, vv = np.meshgrid(np.exp(lo + fb * (hi - lo)), v0 + fv * (v1 - v0), indexing="ij")
    return np.stack([bb.ravel(), vv.ravel()], axis=1)


def measure(model, scene) -> dict:
    """The model's render of `scene` against the x100 FDM, on p (as the validation the file carries): NMSE, pitch
    (cents, steady half), harmonics 1-10 each at its own pitch (mean |dB|); and u as a file would hold it, to play."""
    from ..metrics import cents, f0_estimate, nmse
    from ..engines.fdm import render_fdm
    from ..engines.operator.engine import render_operator
    from ..errors import DomainError
    from ..io.audio import remove_dc

    t0 = time.perf_counter()
    ref = render_fdm(scene, oversample=TRUTH_OVERSAMPLE)
    out = {"fdm_seconds": time.perf_counter() - t0, "truth_u": remove_dc(ref.u, scene.sample_rate)}
    try:
        r = render_operator(scene, model=model)
    except DomainError as e:
        out["error"] = str(e)
        return out
    sr, n = scene.sample_rate, min(len(r.p), len(ref.p))
    st = L.steady(n)
    fx, fr = f0_estimate(r.p[:n], sr), f0_estimate(ref.p[:n], sr)
    h = L.harmonic_levels_db(r.p[st], ref.p[st], sr)
    out.update(nmse=nmse(r.p[:n], ref.p[:n]), cents=cents(fx, fr), f0_hz=fx, f0_ref_hz=fr,
               harm_db=h["mean_abs_diff_db"], levels=h, file_u=remove_dc(r.u, sr))
    return out


def _scene_of(model):
    from ..scene import Scene

    d = dict(model.meta.scene)
    d["duration"] = SECONDS
    return Scene.from_dict(d)


def _map_plot(rows: list[dict], domain, plt) -> str:
    """Two maps of the box: |pitch error| (cents, log colour) and harmonics' mean |dB|; each bow a square with its
    number; grey: the note does not speak within the second; black: the rollout left the model's states."""
    from matplotlib.colors import LogNorm, Normalize

    b0, b1, v0, v1 = domain.box
    from matplotlib.ticker import FixedLocator, NullLocator

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), layout="constrained")
    n = int(round(math.sqrt(len(rows)))) or 1
    size = 3400 / n  # marker area in points^2: the squares nearly tile the box at any grid
    for ax, key, label, norm, fmt in (
            (axes[0], "cents", "|pitch error| (cents)", LogNorm(0.01, 100, clip=True), "{:+.2f}"),
            (axes[1], "harm_db", "harmonics 1-10, mean |dB difference|", Normalize(0, 20, clip=True), "{:.1f}")):
        good = [r for r in rows if r.get(key) is not None and math.isfinite(r[key])]
        other = [r for r in rows if r not in good]
        if good:
            sc = ax.scatter([r["beta"] for r in good], [r["vb"] for r in good], c=[abs(r[key]) for r in good],
                            norm=norm, cmap="viridis_r" if key == "cents" else "magma_r", marker="s", s=size,
                            edgecolors="#333", linewidths=0.5)
            fig.colorbar(sc, ax=ax, label=label, fraction=0.05)
            for r in good:
                v = abs(r[key])
                dark = norm(v) > 0.5  # both colour maps run from light (good) to dark (bad)
                ax.annotate(fmt.format(r[key]), (r["beta"], r["vb"]), ha="center", va="center", fontsize=8.5,
                            color="white" if dark else "black")
        for r in other:
            silent = not r["speaks"]
            ax.scatter([r["beta"]], [r["vb"]], marker="s", s=size, c="#cccccc" if silent else "#222222",
                       edgecolors="#333", linewidths=0.5)
            ax.annotate("silent" if silent else "left", (r["beta"], r["vb"]), ha="center", va="center",
                        fontsize=8, color="#333" if silent else "white")
        ax.set_xscale("log")
        ticks = sorted({b0, b1, *(r["beta"] for r in rows)})
        ax.xaxis.set_major_locator(FixedLocator(ticks))  # the box's edges and the bows: log minor labels collide
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xticklabels([f"{t:.3g}" for t in ticks])
        ax.set_xlim(b0 / 1.25, b1 * 1.25)
        ax.set_ylim(v0 - 0.08 * (v1 - v0), v1 + 0.08 * (v1 - v0))
        ax.add_patch(plt.Rectangle((b0, v0), b1 - b0, v1 - v0, fill=False, ls="--", lw=1, ec="#555"))
        ax.set_xlabel("F_B / w (log)")
        ax.set_ylabel("v_B (m/s)")
        ax.set_title(label)
        ax.grid(False)
    return H.svg(fig)


def _validation_table(v: dict) -> str:
    cols = [("nmse", "NMSE(p)", ".3g"), ("ncc_percent", "NCC (%)", ".4f"), ("cents", "pitch (cents)", "+.3f"),
            ("harmonic_error_db", "harmonic error (dB)", ".3f"), ("lsd_db", "log-spectral distance (dB)", ".3f")]
    if "points" in v:
        def speaks(p) -> str:  # where the truth rests (the validation records say), whether the model does too
            if p.get("speaks") or p.get("truth_sounds") is not False or "op_sounds" not in p:
                return "yes" if p.get("speaks") else "no"
            return "no; the model " + ("sounds" if p["op_sounds"] else "rests")
        rows = [[H.num(p.get('beta'), '.4g'), H.num(p.get('vb'), '.4g'), speaks(p),
                 *[H.num(p.get(k), f) for k, _, f in cols]] for p in v["points"]]
        t = H.table(["F_B / w", "v_B", "speaks", *[c for _, c, _ in cols]], rows, set(range(3, 8)))
        return (f'<p class="why">{H.esc(v.get("grid"))} x {H.esc(v.get("grid"))} grid of the box (cell centres), '
                f'{H.esc(v.get("seconds"))} s from rest at the model\'s f0 vs FDM x{H.esc(v.get("ref_oversample"))}: '
                f'median NMSE(p) '
                f'{H.num(v.get("nmse"), ".3g")} where the note speaks, worst {H.num(v.get("nmse_max"), ".3g")}. The '
                f'harmonic error here is compare\'s (peaks at the reference\'s pitch).</p>' + t)
    row = [H.num(v.get(k), f) for k, _, f in cols]
    return (f'<p class="why">{H.esc(v.get("seconds"))} s from the scene\'s initial state vs FDM '
            f'x{H.esc(v.get("ref_oversample"))}: in '
            f'sample (training took its window starts from this trajectory).</p>'
            + H.table([c for _, c, _ in cols], [row], set(range(5))))


def _meta_card(path, m) -> str:
    d, meta = m.domain, m.meta
    t = meta.training
    items = [("file", str(path)), ("id", m.id), ("format", f"{meta.format} v{meta.format_version}"),
             ("bows", d.describe_bows()), ("friction shape a", f"{d.a:g}"),
             ("state band", f"q {d.q_lo:.3g}..{d.q_hi:.3g}, p {d.p_lo:.3g}..{d.p_hi:.3g} (m/s)"),
             ("window", f"{d.window:.4g} tau"),
             ("trained for scene", ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) else f"{k} {v}"
                                             for k, v in meta.scene.items())),
             ("network", ", ".join(f"{k} {v}" for k, v in meta.net.items())),
             ("training", f"{t.get('seconds')} s, {t.get('steps_done')} steps, {t.get('optimizer')}, "
                          f"{'hybrid (FDM data + physics)' if t.get('hybrid') else 'physics only'}, final loss "
                          f"{H.num(t.get('final_loss'), '.3g')}")]
    sel = t.get("selected")
    if sel:
        items.append(("selection", ", ".join(f"{k} {H.num(v, '.3g') if isinstance(v, float) else v}"
                                             for k, v in sel.items() if k not in ("bows", "from_state"))
                      + " (weights kept: the best rollout score from half the budget on; out of sample)"))
    return H.kv(items)


def _players_for(rows: list[dict], sr: int, what) -> str:
    items = []
    for r in rows:
        if "file_u" not in r:
            continue
        g = H.common_gain(r["file_u"], r["truth_u"])
        items.append(H.player(f"model, {what(r)}", f"cents {H.num(r.get('cents'), '+.2f')}, harmonics "
                              f"{H.num(r.get('harm_db'), '.2f')} dB, NMSE(p) {H.num(r.get('nmse'), '.3g')}",
                              r["file_u"], sr, g))
        items.append(H.player(f"truth, {what(r)}", f"FDM x{TRUTH_OVERSAMPLE}, the same bow, at the model's level",
                              r["truth_u"], sr, g))
    return f'<div class="players">{"".join(items)}</div>' if items else ""


def model_section(path, m, grid: int, progress, plt) -> tuple[str, dict]:
    """One model's section and its summary row."""
    anchor = "model-" + H.slug(path.stem)
    kind = "range model" if m.domain.is_range else "point model"
    head = [f'<section id="{anchor}"><h2>{H.esc(path.name)} <small>({kind})</small></h2>']
    if m.failure:
        head.append(f'<p class="note bad">{H.esc(m.failure)}: {H.esc(unpicked_text(m.meta))}</p>')
    head.append(f'<div class="card">{_meta_card(path, m)}</div>')
    head.append("<h3>Validation the file carries</h3>" + _validation_table(m.meta.validation or {}))
    base = _scene_of(m)
    sr = base.sample_rate
    summary = {"name": path.name, "kind": kind, "anchor": anchor, "failure": m.failure,
               "validation": (m.meta.validation or {}).get("nmse")}
    if not m.domain.is_range:
        progress(f"models report: {path.name}: its own scene, {SECONDS:g} s against a x{TRUTH_OVERSAMPLE} FDM")
        r = measure(m, base)
        summary.update(cents=r.get("cents"), harm=r.get("harm_db"), error=r.get("error"))
        body = ["<h3>Measured now: its own scene</h3>",
                f'<p class="why">{SECONDS:g} s from the scene\'s initial state ({H.esc(base.describe())}), the model '
                f'against the FDM x{TRUTH_OVERSAMPLE}, on p: pitch over the steady half, harmonics 1-10 each at its own '
                f'pitch.</p>']
        if r.get("error"):
            body.append(f'<p class="note bad">{H.esc(r["error"])}</p>')
        else:
            body.append(H.table(["NMSE(p)", "pitch (cents)", "harmonics, mean |dB difference|", "f0 (Hz)"],
                                [[H.num(r["nmse"], ".3g"), H.num(r["cents"], "+.3f"), H.num(r["harm_db"], ".3f"),
                                  H.num(r["f0_hz"], ".4f")]], {0, 1, 2, 3}))
            body.append(_players_for([r], sr, lambda _: "its own scene"))
        return "\n".join(head + body) + "</section>", summary
    from ..training.ranges import speaks

    bows = held_out_bows(m.domain, grid)
    rows = []
    for i, (b, v) in enumerate(bows):
        sc = base.replace(fb=float(b) * base.omega, vb=float(v), q0=0.0, p0=0.0)
        row = {"beta": float(b), "vb": float(v), "speaks": bool(speaks(b, v, m.domain.a, base.f0, SECONDS))}
        if row["speaks"]:
            progress(f"models report: {path.name}: bow {i + 1}/{len(bows)} (F_B / w {b:.4g}, v_B {v:.4g}), "
                     f"{SECONDS:g} s against a x{TRUTH_OVERSAMPLE} FDM")
            row.update(measure(m, sc))
        else:
            progress(f"models report: {path.name}: bow {i + 1}/{len(bows)} (F_B / w {b:.4g}, v_B {v:.4g}) does "
                     f"not speak within {SECONDS:g} s: skipped")
        rows.append(row)
    ok = [r for r in rows if r.get("harm_db") is not None and math.isfinite(r["harm_db"])]
    med = lambda k: float(np.median([abs(r[k]) for r in ok if math.isfinite(r[k])])) if ok else None  # noqa: E731
    summary.update(cents=med("cents"), harm=med("harm_db"), bows=len(bows), measured=len(ok),
                   left=sum(1 for r in rows if r.get("error")))
    table_rows = [[f"{r['beta']:.4g}", f"{r['vb']:.4g}",
                   "yes" if r["speaks"] else "no (skipped)",
                   H.num(r.get("nmse"), ".3g"), H.num(r.get("cents"), "+.3f"), H.num(r.get("harm_db"), ".3f"),
                   r.get("error", "ok" if "nmse" in r else "")] for r in rows]
    picks = sorted(ok, key=lambda r: r["harm_db"])
    picks = [picks[0], picks[len(picks) // 2], picks[-1]] if len(picks) >= 3 else picks
    names = ["best", "median", "worst"] if len(picks) == 3 else ["" for _ in picks]
    for r, nm in zip(picks, names):
        r["pick"] = nm
    body = [f"<h3>Measured now: {len(bows)} held-out bows</h3>",
            f'<p class="why">{grid} x {grid} bows over the box, a quarter cell off the validation grid above (so '
            f'neither training, selection nor validation used them), {SECONDS:g} s from rest at f0 {base.f0:g} Hz '
            f'against a x{TRUTH_OVERSAMPLE} FDM each, on p. Median over the {len(ok)} measured: pitch '
            f'{H.num(summary["cents"], ".2f")} cents, harmonics {H.num(summary["harm"], ".2f")} dB. '
            f'<code>--report-grid N</code> sets the grid (N x N FDM runs: the time grows as N squared).</p>',
            H.figure(_map_plot(rows, m.domain, plt),
                     "Where in its box the model is good: left, the pitch error (cents, signed in the squares); "
                     "right, how far harmonics 1-10 are from the truth's (mean |dB|). Dashed: the box."),
            H.table(["F_B / w", "v_B", "speaks", "NMSE(p)", "pitch (cents)", "harmonics, mean |dB|", "rollout"],
                    table_rows, {0, 1, 3, 4, 5}),
            "<h3>Listen: held-out bows (best, median and worst by harmonics)</h3>",
            _players_for(picks, sr, lambda r: f"{r.get('pick', '')} F_B / w {r['beta']:.3g}, v_B {r['vb']:.3g}")]
    return "\n".join(head + body) + "</section>", summary


def models_page(found: list, grid: int = 3, progress=lambda s: None) -> str:
    from .. import __version__

    plt = H.setup_matplotlib()
    t0 = time.perf_counter()
    sections, summaries = [], []
    for path, m, why in found:
        if m is None:
            sections.append(f'<section><h2>{H.esc(path.name)}</h2><p class="note bad">unreadable: {H.esc(why)}'
                            f'</p></section>')
            summaries.append({"name": path.name, "kind": "unreadable", "anchor": "", "failure": why})
            continue
        s, summ = model_section(path, m, grid, progress, plt)
        sections.append(s)
        summaries.append(summ)
    rows = []
    for s in summaries:
        name = ("html", f'<a href="#{s["anchor"]}">{H.esc(s["name"])}</a>') if s["anchor"] else s["name"]
        rows.append([name, s["kind"], H.num(s.get("validation"), ".3g"), H.num(s.get("cents"), ".3f"),
                     H.num(s.get("harm"), ".3f"), s.get("failure") or s.get("error") or ""])
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    body = [f"<h1>Models report</h1><p class=\"sub\">bowsynth models --report, grid {grid} x {grid} &middot; "
            f"bowsynth {H.esc(__version__)} &middot; {when} &middot; measured in "
            f"{time.perf_counter() - t0:.0f} s</p>",
            '<p class="why">Every model file found (./models, then the shipped ones). For each: what the file '
            'carries (its domain, training, selection and validation) and what this page measured when it was made '
            'against a x100 FDM: a point model at its own scene, a range model on held-out bows over its box. '
            'Pitch and harmonics are what a listener hears (docs/measures.md); NMSE is the paper\'s score.</p>',
            H.table(["model", "kind", "validation NMSE(p) (carried)", "pitch error, cents (measured; a range "
                     "model: median |cents|)", "harmonics, mean |dB| (measured; a range model: median)", "note"],
                    rows, {2, 3, 4}, cls="summary"),
            *sections]
    return H.page("bowsynth models report", "\n".join(body))


def write_models_report(path, found: list, grid: int = 3, force: bool = False, progress=lambda s: None) -> None:
    H.write_page(path, models_page(found, grid, progress), force=force)


def check_report_path(path, grid: int, force: bool = False) -> None:
    from ..errors import UsageError
    from ..io.outfile import check_output_path, is_stdout

    if is_stdout(path):
        raise UsageError("--report writes a page to open in a browser; give an .html file, not - (standard output)")
    if path.suffix.lower() not in (".html", ".htm"):
        raise UsageError(f"--report writes an HTML page; give a .html file name, got {path}")
    if not 1 <= grid <= 10:
        raise UsageError(f"--report-grid must be 1 to 10 (N x N FDM runs per range model), got {grid}")
    check_output_path(path, force=force)
