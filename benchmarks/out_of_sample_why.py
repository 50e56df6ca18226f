"""Why two out-of-sample rows of `bowsynth bench` miss the 10x target, and where the fb 1000 model's log-spectral
distance comes from (docs/BENCHMARKS.md, "Out of sample"). About 15 s.

    PYTHONPATH=. .venv/bin/python benchmarks/out_of_sample_why.py
"""

import numpy as np
from scipy import signal as sps

from bowsynth import Scene, load_model, make_scene, render_fdm, render_operator
from bowsynth.metrics import nmse
from bowsynth.engines.fdm import TRUTH_OVERSAMPLE
from bowsynth.engines.operator.choose import SHIPPED_DIR


def onset_shift():
    """fb 10 from states of the slow onset: RMS error per 0.2 s, and the largest relative difference of the per-window
    peak |p| (the envelope) against the FDM."""
    m = load_model(SHIPPED_DIR / "paper-fb10.safetensors")
    sc = make_scene("paper-fb10")
    path = render_fdm(sc.replace(duration=0.05, sample_rate=4 * sc.sample_rate), oversample=TRUTH_OVERSAMPLE // 4)
    print("fb 10, 1 s renders from the rest trajectory at t = m T (m = 2, 2.25, 2.5):")
    print("| start | NMSE(p) | RMS error per 0.2 s | envelope, largest relative difference |")
    print("|---|---|---|---|")
    env = lambda x: np.array([np.abs(x[k * 441:(k + 1) * 441]).max() for k in range(len(x) // 441)])  # noqa: E731
    for mt in (2.0, 2.25, 2.5):
        i = int(round(mt / sc.f0 * path.scene.sample_rate))
        s = sc.replace(q0=float(path.q[i]), p0=float(path.p[i]))
        r, ref = render_operator(s, model=m), render_fdm(s, oversample=TRUTH_OVERSAMPLE)
        e = r.p - ref.p
        rms = " ".join(f"{np.sqrt(np.mean(e[k * 8820:(k + 1) * 8820] ** 2)):.1e}" for k in range(5))
        print(f"| {mt:g} T | {nmse(r.p, ref.p):.2e} | {rms} | {np.abs(env(r.p) / env(ref.p) - 1).max():.1e} |")


def onset_windows():
    """fb 10: one-window NMSE(p) from states of the rest trajectory at t = (m + f) T."""
    from bowsynth.analysis.out_of_sample import window_errors

    m = load_model(SHIPPED_DIR / "paper-fb10.safetensors")
    sc = make_scene("paper-fb10")
    path = render_fdm(sc.replace(duration=0.25, sample_rate=4 * sc.sample_rate), oversample=TRUTH_OVERSAMPLE // 4)
    per = path.scene.sample_rate / sc.f0
    print("\nfb 10, one-window NMSE(p) from the rest trajectory at t = (m + f) T:")
    print("| m | f = 0 (a window start of the render from rest) | f = 0.25 | f = 0.5 | f = 0.75 |")
    print("|---|---|---|---|---|")
    for mm in (0, 1, 2, 3, 5, 10, 20):
        idx = [int(round((mm + f) * per)) for f in (0.0, 0.25, 0.5, 0.75)]
        e = window_errors(m, np.stack([path.q[idx], path.p[idx]], 1), sc)
        print(f"| {mm} | " + " | ".join(f"{v:.1e}" for v in e) + " |")


def spectrum_bands():
    """fb 1000: the operator's Welch power against the FDM x100's, mean dB difference per band (1 s from rest)."""
    m = load_model(SHIPPED_DIR / "paper-fb1000.safetensors")
    sc = make_scene("paper-fb1000")
    r, ref = render_operator(sc, model=m), render_fdm(sc, oversample=TRUTH_OVERSAMPLE)
    f, px = sps.welch(np.asarray(r.p, float), sc.sample_rate, nperseg=4096)
    _, pr = sps.welch(ref.p, sc.sample_rate, nperseg=4096)
    print("\nfb 1000, 1 s from rest: power of the operator's p against the FDM x100's, by band:")
    print("| band (Hz) | reference peak in band (dB below the spectrum's peak) | operator - reference (dB, mean) |")
    print("|---|---|---|")
    for lo, hi in ((0, 500), (500, 1000), (1000, 2000), (2000, 4000), (4000, 8000)):
        b = (f >= lo) & (f < hi)
        print(f"| {lo}-{hi} | {10 * np.log10(pr[b].max() / pr.max()):.1f} | "
              f"{np.mean(10 * np.log10(px[b] / pr[b])):+.1f} |")


def margin_states():
    """One-window NMSE(p) of held-out states by their distance from the band (fraction of the domain's box)."""
    from bowsynth.analysis.out_of_sample import band_distance, band_states, window_errors

    print("\nOne-window NMSE(p) of 64 held-out states (seed 1) by distance from the band:")
    print("| model | distance (of the box) | states | median | worst |")
    print("|---|---|---|---|---|")
    for name in ("paper-fb100", "paper-fb1000"):
        m = load_model(SHIPPED_DIR / f"{name}.safetensors")
        sc = Scene(**m.meta.scene)
        x = band_states(m, 64, np.random.default_rng(1), away=0.0)
        e, d = window_errors(m, x, sc), band_distance(m, x, sc)
        for lo, hi in ((0, 0.01), (0.01, 0.025), (0.025, 0.05), (0.05, 1.0)):
            b = (d >= lo) & (d < hi)
            if b.any():
                print(f"| {name} | {lo:g}-{hi:g} | {b.sum()} | {np.median(e[b]):.1e} | {e[b].max():.1e} |")


if __name__ == "__main__":
    onset_shift()
    onset_windows()
    spectrum_bands()
    margin_states()
