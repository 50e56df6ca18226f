"""The report page of a fit: the target and the fitted note (and curves) to listen to side by side, their harmonics,
the bows the search scored over the bow plane with those that sound as near, the curves with their spread."""

from __future__ import annotations

import numpy as np

from . import html as H


def _levels(x, rate: float) -> np.ndarray:
    from ..metrics import harmonic_levels

    half = len(x) // 2
    return harmonic_levels(np.asarray(x[half:], float), rate)


def harmonics_figure(plt, target, fitted, rate: float) -> str:
    fig, ax = plt.subplots(figsize=(7.5, 2.8))
    k = np.arange(1, 11)
    for x, name, mark in ((target, "target", "o"), (fitted, "fitted note", "x")):
        ax.plot(k, _levels(x, rate), mark + "-", label=name, ms=6)
    ax.set_xlabel("harmonic")
    ax.set_ylabel("dB re the fundamental")
    ax.axhline(-50, color="0.6", lw=0.8, ls=":")
    ax.legend(loc="upper right")
    return H.figure(H.svg(fig), "Harmonics 1-10 over the notes' second half, each at its own pitch; below the dotted "
                                "line (-50 dB) the instrument's targets do not count them.")


def landscape_figure(plt, fit) -> str:
    from ..fit.held import within

    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    seen = [c for c in fit.seen if np.isfinite(c.loss)]
    b = np.array([c.beta for c in seen])
    v = np.array([c.vb for c in seen])
    loss = np.array([c.loss for c in seen])
    near = loss <= within(fit.best)
    sc = ax.scatter(b[~near], v[~near], c=np.log10(loss[~near]), s=9, cmap="viridis_r")
    ax.scatter(b[near], v[near], s=22, facecolors="none", edgecolors="C3", label="sounds as near as the best")
    ax.plot([fit.best.beta], [fit.best.vb], "*", color="C3", ms=14, label="the fit")
    ax.set_xscale("log")
    ax.set_xlabel("F_B / w")
    ax.set_ylabel("v_B (m/s)")
    fig.colorbar(sc, ax=ax, label="log10 loss")
    ax.legend(loc="lower right", fontsize=8)
    return H.figure(H.svg(fig), "Every bow the search played against the whole target, by its loss; circled, those "
                                "within twice the best loss (plus the loss's own roughness): the sound does not tell "
                                "them from the fit.")


def curves_figure(plt, curves) -> str:
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 2.8))
    for ax, values, rel, name in ((axes[0], curves.beta, curves.spread[:, 0], "F_B / w"),
                                  (axes[1], curves.vb, curves.spread[:, 1], "v_B (m/s)")):
        err = np.where(np.isfinite(rel), rel * values, np.nan)
        ax.errorbar(curves.times, values, yerr=err, fmt="o-", ms=4, capsize=2)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(name)
    return H.figure(H.svg(fig), "The fitted curves at their breakpoints; the bars, the change of each breakpoint that "
                                "moves the loss by its own roughness (none drawn: the sound does not bend the loss "
                                "there).")


def fit_page(target, fit, render, curves=None) -> str:
    """The page (HTML text): `render` plays the fitted scene(s) as `bowsynth render` would (api.render)."""
    from ..fit.surrogate import note_scene
    from ..fit.write import determined
    from ..io.audio import remove_dc

    plt = H.setup_matplotlib()
    rate, seconds = target.sample_rate, target.n / target.sample_rate
    b = fit.best
    held = remove_dc(np.asarray(render(note_scene(b.f0, b.beta, b.vb, seconds, rate)).q, float), rate)
    sounds = [("target", f"{target.path}, its first {seconds:.3g} s", target.x),
              ("the held fit", f"f0 {b.f0:.6g} Hz, F_B / w {b.beta:.5g}, v_B {b.vb:.5g}", held)]
    if curves is not None:
        cx = remove_dc(np.asarray(render(curves.scene(seconds, rate)).q, float), rate)
        sounds.append(("the fitted curves", f"f0 {curves.f0:.6g} Hz, {len(curves.times)} breakpoints", cx))
    normed = [(t, w, x / (np.max(np.abs(x)) or 1.0)) for t, w, x in sounds]
    gain = H.common_gain(*[x for _, _, x in normed])
    players = "".join(H.player(t, w, x, rate, gain) for t, w, x in normed)
    ch = fit.checked or {}
    facts = [("fitted", f"f0 {b.f0:.6g} Hz, F_B {fit.fb:.6g} (F_B / w {b.beta:.5g}), v_B {b.vb:.5g}"),
             ("determined", f"F_B / w {determined(fit, 'beta')}, v_B {determined(fit, 'vb')}"),
             ("sounds alike", "; ".join(f"F_B / w {c.beta:.4g}, v_B {c.vb:.4g}" for c in fit.alike) or "none found"),
             ("against the target", f"harmonics {H.num(ch.get('harmonics_db'), '.2f')} dB (median), pitch "
                                    f"{H.num(ch.get('pitch_cents'), '+.2f')} cents, onset {H.num(ch.get('onset_ms'), '+.1f')} ms"),
             ("search", f"{fit.evaluations} notes played in {fit.seconds:.1f} s"
                        + (" (interrupted)" if fit.interrupted else ""))]
    if curves is not None and curves.checked:
        cc = curves.checked
        facts.append(("curves against the target", f"per 100 ms frame: harmonics {H.num(cc.get('harmonics_db'), '.2f')}"
                                                   f" dB (median), pitch {H.num(cc.get('pitch_cents'), '.2f')} cents"))
    body = (f"<h1>bowsynth fit: {H.esc(target.path)}</h1><p class='sub'>The bow that makes the operator sound like "
            f"the target, how well the sound determines it, and the fitted note as <code>bowsynth render</code> plays it."
            f"</p><div class='card'>{H.kv(facts)}</div>"
            f"<h2>Listen</h2><div class='players'>{players}</div>"
            f"<h2>Harmonics</h2>{harmonics_figure(plt, target.x, held, rate)}"
            f"<h2>The bow plane</h2>{landscape_figure(plt, fit)}")
    if curves is not None:
        body += f"<h2>Curves</h2>{curves_figure(plt, curves)}"
    return H.page(f"bowsynth fit: {target.path}", body)
