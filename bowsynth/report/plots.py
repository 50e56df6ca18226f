"""The report's figures (matplotlib, Agg, inline SVG): harmonic levels, the pitch track, the onset envelope and the
spectrograms of a rendered note against its truth."""

from __future__ import annotations

import math

import numpy as np

from ..analysis.compare import Comparison
from . import html as H
from . import listen as L


def harmonic_plot(m: dict, plt) -> str:
    h, r = m["harm"], m["roles"]
    k = np.arange(1, len(h["levels_db"]) + 1)
    fig, ax = plt.subplots(figsize=(7.2, 2.9))
    lo = np.nanmin(np.concatenate([h["levels_db"], h["levels_ref_db"], [-40.0]]))
    base = min(-40.0, math.floor((lo - 5) / 10) * 10)
    w = 0.38
    for off, vals, lab, col in ((-w / 2, h["levels_ref_db"], f"{r['ref']} (reference)", "#3b4a6b"),
                                (w / 2, h["levels_db"], r["file"], "#e07b39")):
        v = np.nan_to_num(vals, nan=base)
        ax.bar(k + off, v - base, w, bottom=base, label=lab, color=col)
    for i, d in enumerate(h["diff_db"]):
        if math.isfinite(d):
            ax.annotate(f"{d:+.1f}" if abs(d) >= 0.05 else "0", (k[i], max(np.nan_to_num(h["levels_db"][i], nan=base),
                                                np.nan_to_num(h["levels_ref_db"][i], nan=base)) + 1.5),
                        ha="center", fontsize=7.5, color="#b3261e" if abs(d) >= 1 else "#5a6372")
    ax.set_xticks(k)
    ax.set_xlabel("harmonic")
    ax.set_ylabel("dB re reference fundamental")
    ax.set_ylim(base, 8)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"harmonic levels (file {h['f0_hz']:.3f} Hz, reference {h['f0_ref_hz']:.3f} Hz); "
                 f"numbers: file - reference, dB")
    return H.svg(fig)


def pitch_plot(m: dict, plt) -> str:
    r = m["roles"]
    t = m["track_t"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.2, 3.6), sharex=True, gridspec_kw={"height_ratios": [1, 1.4]})
    a1.plot(t, m["track_ref"], color="#3b4a6b", lw=1.6, label=r["ref"])
    a1.plot(t, m["track_x"], color="#e07b39", lw=1, ls="--", label=r["file"])
    a1.set_ylabel("Hz")
    a1.legend(loc="lower right", fontsize=8)
    a1.set_title("pitch over time (upward zero crossings, frames of six periods)")
    a2.axhline(0, color="#3b4a6b", lw=1)
    a2.plot(t, L.cents(m["track_x"], m["track_ref"]), color="#e07b39", lw=1.2, label=f"{r['file']} vs {r['ref']}")
    if "track_fdm" in m:
        a2.plot(t, L.cents(m["track_fdm"], m["track_ref"]), color="#6a9f58", lw=1, label=f"audio-rate FDM vs {r['ref']}")
    on = m["onset"][r["ref"]]
    if math.isfinite(on):
        for a in (a1, a2):
            a.axvline(on, color="#999", lw=0.8, ls=":")
        c = L.cents(m["track_x"], m["track_ref"])[t > on]
        fin = c[np.isfinite(c)]
        if len(fin):  # the onset's wild first frames would hide the note's few cents
            span = max(1.0, 1.3 * float(np.max(np.abs(fin))))
            a2.set_ylim(-span, span)
    a2.set_ylabel("cents")
    a2.set_xlabel("t (s); dotted: the reference's onset")
    a2.legend(loc="lower right", fontsize=8)
    return H.svg(fig)


def onset_plot(c: Comparison, m: dict, plt) -> str:
    r, sr = m["roles"], m["sr"]
    x, ref = c.series[r["file"]][:m["n"]], c.series[r["ref"]][:m["n"]]
    on = [v for v in m["onset"].values() if math.isfinite(v)]
    late = max(on) if on else 0.0
    lo, hi = (0.0, 0.05) if late < 0.04 else (late - 0.025, late + 0.025)
    i0, i1 = int(lo * sr), min(len(x), int(hi * sr))
    t = np.arange(i0, i1) / sr
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.0), gridspec_kw={"width_ratios": [1.3, 1]})
    a1.plot(t * 1e3, ref[i0:i1], color="#3b4a6b", lw=2, alpha=0.6, label=r["ref"])
    a1.plot(t * 1e3, x[i0:i1], color="#e07b39", lw=1, ls="--", label=r["file"])
    a1.set_xlabel("t (ms)")
    a1.set_title(f"the onset, {lo * 1e3:.0f}-{hi * 1e3:.0f} ms")
    a1.legend(loc="upper left", fontsize=8)
    tt = np.arange(m["n"]) / sr
    for sig, lab, col, ls in ((ref, r["ref"], "#3b4a6b", "-"), (x, r["file"], "#e07b39", "--")):
        env = L.rms_envelope(sig, sr, m["f_hint"])
        a2.plot(tt, 20 * np.log10(env / (np.max(env) or 1) + 1e-12), color=col, lw=1.2, ls=ls, label=lab)
        o = m["onset"][lab]
        if math.isfinite(o):
            for a in (a1, a2):
                if a is a2 or lo <= o <= hi:
                    a.axvline(o * (1e3 if a is a1 else 1), color=col, lw=0.9, ls=":")
    a2.set_ylim(-60, 3)
    a2.set_xlabel("t (s)")
    a2.set_ylabel("dB")
    a2.set_title("one-period RMS; dotted: onset (half the final RMS)")
    a2.legend(loc="lower right", fontsize=8)
    return H.svg(fig)


def spectrogram_plot(c: Comparison, m: dict, plt) -> str:
    from matplotlib import mlab

    r, sr = m["roles"], m["sr"]
    sigs = [(r["file"], c.series[r["file"]][:m["n"]]), (r["ref"], c.series[r["ref"]][:m["n"]])]
    nfft = int(min(4096, max(256, 2 ** round(math.log2(max(256, m["n"] // 16))))))
    specs = [mlab.specgram(sig, NFFT=nfft, Fs=sr, noverlap=nfft * 3 // 4, window=mlab.window_hanning)
             for _, sig in sigs]
    top = max(float(s.max()) for s, _, _ in specs) or 1.0  # one scale for both: a difference shows as one
    fmax = min(sr / 2, max(2000.0, 12 * m["f_hint"]))
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.2), sharey=True)
    for ax, (lab, _), (s, f, t) in zip(axes, sigs, specs):
        keep = f <= fmax * 1.02
        im = ax.pcolormesh(t, f[keep], 10 * np.log10(s[keep] / top + 1e-30), cmap="magma", vmin=-90, vmax=0,
                           shading="auto", rasterized=True)
        ax.set_title(f"spectrogram: {lab}")
        ax.set_xlabel("t (s)")
        ax.grid(False)
    axes[0].set_ylabel("Hz")
    axes[0].set_ylim(0, fmax)
    fig.colorbar(im, ax=list(axes), label="dB re the louder peak", fraction=0.025, pad=0.01)
    return H.svg(fig)
