"""`bowsynth compare X --report R.html`: the comparison `compare` already computed, made audible and visible.

Everything here is drawn from a Comparison (bowsynth.analysis.compare): its series are the file and the references compare
rendered, so no reference is computed twice. A mix gets a table of its notes and a section for each of its worst
notes (through the stems, as compare_mix measures them)."""

from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np

from ..analysis.compare import HIGH_OVERSAMPLE, ROWS, Comparison
from ..analysis.metrics import onset_time
from . import html as H
from . import listen as L

TRUTH = f"FDM x{HIGH_OVERSAMPLE}"

# compare's metric rows (same names and formats as the table it prints), with what each measures
WHAT = {
    "nmse": "mean squared difference / variance of the reference (the paper's NMSE). Phase-sensitive: a pitch "
            "drift far too small to hear still grows it over a long note",
    "ncc_percent": "Pearson correlation of the two waveforms; 100 % is the same shape",
    "f0_hz": "pitch of the first signal: interpolated upward zero crossings over the steady half of the note",
    "f0_ref_hz": "the same, of the reference",
    "cents": "1200 log2(f0 / f0 of reference); 100 cents is a semitone, a few cents are heard on a held note",
    "harmonic_error_db": "mean |dB difference| of the spectral peaks of harmonics 1-10 at the reference's pitch "
                         "(steady half); the bar chart below fits each signal at its own pitch",
    "lsd_db": "RMS over frequency of the dB difference of the two power spectra (Welch)",
}


def roles(c: Comparison) -> dict:
    """Which series is the file, which the reference the page measures against, which the audio-rate FDM."""
    labels = list(c.series)
    if "file" in c.series:
        ref = TRUTH if TRUTH in c.series else "FDM"
        return {"file": "file", "ref": ref, "fdm": "FDM" if ref == TRUTH else None,
                "ref_name": "the truth (FDM x100)" if ref == TRUTH else "the audio-rate FDM"}
    return {"file": labels[0], "ref": labels[-1], "fdm": None, "ref_name": labels[-1]}


def _metrics_table(c: Comparison) -> str:
    cols = list(c.columns)
    rows = []
    for key, name, fmt in ROWS:
        rows.append([name, *[H.num(c.columns[k].get(key), fmt) for k in cols], WHAT.get(key, "")])
    for label, s in c.seconds.items():
        if s is not None:
            what = ("the file's render, as its metadata recorded it" if label == "file" else
                    f"this run's {label.replace('fdm_x', 'FDM at x').replace('fdm', 'audio-rate FDM')} reference")
            rows.append([f"render time, {label} (s)", f"{s:.4f}", *[""] * (len(cols) - 1), f"wall time: {what}"])
    j = c.to_json()
    if j["speed_ratio_fdm_over_file"]:
        rows.append(["speed: FDM time / file time", f"{j['speed_ratio_fdm_over_file']:.2f}x",
                     *[""] * (len(cols) - 1), "how much longer the audio-rate FDM took than the file's render"])
    return H.table(["metric", *cols, "what it measures"], rows, set(range(1, len(cols) + 1)), cls="metrics",
                   what_last=True)


def listener(c: Comparison, k: int | None = None) -> dict:
    """The report's own measures (GUIDE section 9) of the file and the audio-rate FDM against the reference: harmonic
    levels at each one's own pitch over compare's steady part, pitch tracks, onsets. k: the sustain's length in
    samples (a stem's note without its bow stop), as compare's pitch_seconds."""
    r = roles(c)
    sr = c.scene.sample_rate if c.scene else 44100
    x, ref = c.series[r["file"]], c.series[r["ref"]]
    n = min(len(x), len(ref))
    st = L.steady(n, k)
    out = {"sr": sr, "roles": r, "steady": st, "n": n, "k": st.stop}
    out["harm"] = L.harmonic_levels_db(x[st], ref[st], sr)
    f_ref = out["harm"]["f0_ref_hz"]
    if r["fdm"]:
        out["harm_fdm"] = L.harmonic_levels_db(c.series[r["fdm"]][st], ref[st], sr)
    hint = f_ref if f_ref > 0 else (c.scene.f0 if c.scene else 100.0)
    out["f_hint"] = hint
    t, fr = L.pitch_track(ref[:n], sr, hint)
    out["track_t"], out["track_ref"] = t, fr
    out["track_x"] = L.pitch_track(x[:n], sr, hint)[1]
    if r["fdm"]:
        out["track_fdm"] = L.pitch_track(c.series[r["fdm"]][:n], sr, hint)[1]
    out["onset"] = {lab: onset_time(c.series[lab][:n], sr, hint, end=st.stop)
                    for lab in (r["file"], r["ref"], r["fdm"]) if lab}
    return out


def _listener_table(m: dict) -> str:
    r, h = m["roles"], m["harm"]
    rows = [["harmonics 1-10, mean |dB difference|", H.num(h["mean_abs_diff_db"], ".3f")]]
    if "harm_fdm" in m:
        rows[0].append(H.num(m["harm_fdm"]["mean_abs_diff_db"], ".3f"))
    rows[0].append("each signal fitted at its own pitch by least squares (steady part); harmonics within 60 dB of "
                   "the reference's fundamental")
    cm = L.cents(m["track_x"], m["track_ref"])
    row = ["pitch track, largest |cents| after the onset", _max_abs(cm, m)]
    if "track_fdm" in m:
        row.append(_max_abs(L.cents(m["track_fdm"], m["track_ref"]), m))
    rows.append(row + ["the worst frame of the pitch track below, between the reference's onset and the end of the "
                       "sustain"])
    on = m["onset"]
    row = [f"onset (ms); the reference: {H.num(_ms(on[r['ref']]), '.1f')}", H.num(_ms(on[r["file"]]), ".1f")]
    if r["fdm"]:
        row.append(H.num(_ms(on[r["fdm"]]), ".1f"))
    rows.append(row + ["first time a one-period RMS reaches half its value at the end of the sustain (under a "
                       "crescendo that end moves it: read it on held notes)"])
    cols = ["file" if r["file"] == "file" else r["file"]] + (["audio-rate FDM"] if r["fdm"] else [])
    return H.table(["listener measure", *[f"{c} vs {m['roles']['ref']}" for c in cols], "what it measures"], rows,
                   set(range(1, len(cols) + 1)), cls="listener", what_last=True)


def _ms(t):
    return None if t is None or not math.isfinite(t) else 1e3 * t


def _max_abs(cents, m) -> str:
    on = m["onset"][m["roles"]["ref"]]
    t = m["track_t"]
    # after the onset and within the sustain: a stem's bow stop is no part of the note's pitch
    keep = (t > (on if math.isfinite(on) else 0)) & (t < m["k"] / m["sr"]) & np.isfinite(cents)
    v = np.abs(cents[keep])
    return f"{v.max():.2f}" if len(v) else "n/a"


def _harmonic_plot(m: dict, plt) -> str:
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


def _pitch_plot(m: dict, plt) -> str:
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


def _onset_plot(c: Comparison, m: dict, plt) -> str:
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


def _spectrogram_plot(c: Comparison, m: dict, plt) -> str:
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


def _players(c: Comparison, m: dict) -> str:
    r, sr = m["roles"], m["sr"]
    n = m["n"]
    x, ref = c.series[r["file"]][:n], c.series[r["ref"]][:n]
    sigs = [x, ref] + ([c.series[r["fdm"]][:n]] if r["fdm"] else [])
    g = H.common_gain(*sigs)
    items = [H.player("the file", f"{r['file']}: the render under test", x, sr, g),
             H.player("the truth" if r["ref"] == TRUTH else "the reference",
                      f"{r['ref']}: the same scene and bow curves" + (", the FDM at 100x the rate" if r["ref"] == TRUTH
                                                                      else ""), ref, sr, g)]
    if r["fdm"]:
        items.append(H.player("the audio-rate FDM", "what you would render instead (--method fdm)",
                              c.series[r["fdm"]][:n], sr, g))
    diff, boost = H.difference_player(x, ref, sr, g, r["ref"])
    items.append(diff)
    who = "The file, the reference and the audio-rate FDM" if r["fdm"] else "The file and the reference"
    raised = f"+{boost:.0f} dB" if boost is not None else "0 dB"
    level = (f"{who} play at one gain (the loudest peaks at -1 dBFS), so loudness differences are real; the "
             f"difference is raised by {raised}.")
    return (f'<p class="why">{level} Audio is embedded as 16-bit PCM WAV.</p>'
            f'<div class="players">{"".join(items)}</div>')


def _scene_card(c: Comparison, meta: dict | None, name: str) -> str:
    from ..engines.operator.choose import scan_models

    items = [("file", name)]
    if c.scene is not None:
        for k, v in c.scene.to_dict().items():
            items.append((k, v if not isinstance(v, list) else ", ".join(f"{val:g} at {t:g} s" for t, val in v)))
    if meta:
        items.append(("engine", meta.get("method", "?")))
        items.append(("signal", f"{meta.get('signal', 'u')} ({'displacement u, m' if meta.get('signal', 'u') == 'u' else 'velocity p, m/s'})"))
        if meta.get("render_seconds") is not None:
            items.append(("render time", f"{meta['render_seconds']:.4f} s"))
        mid = meta.get("model")
        if mid:
            found = [(p, m) for p, m, _ in scan_models() if m is not None and m.id == mid]
            if found:
                p, m = found[0]
                kind = "range model" if m.domain.is_range else "point model"
                items.append(("model", f"{mid} ({kind}, {p})"))
                items.append(("model's domain", m.domain.describe_bows()))
            else:
                items.append(("model", f"{mid} (its file is not among the models found here)"))
        items.append(("DC", "removed (5 Hz high-pass); the references filtered the same way"
                      if meta.get("dc") not in (None, "kept") else "kept"))
    return H.kv(items)


def comparison_section(c: Comparison, meta: dict | None, name: str, k: int | None = None, anchor: str = "",
                       heading: str | None = None) -> str:
    """One comparison as a page section: players, metrics, harmonics, pitch, onset, spectrograms, scene."""
    plt = H.setup_matplotlib()
    m = listener(c, k)
    r = m["roles"]
    ref_note = ("" if r["ref"] == TRUTH else
                f'<p class="note">No x{HIGH_OVERSAMPLE} FDM here (--reference audio or two files): the reference is '
                f'{H.esc(r["ref_name"])}, itself not exact.</p>')
    notes = "".join(f'<p class="note">{H.esc(n)}</p>' for n in c.notes)
    s = [f'<section id="{anchor}">' if anchor else "<section>"]
    if heading:
        s.append(f"<h2>{H.esc(heading)}</h2>")
    s += [ref_note, notes,
          "<h3>Listen</h3>", _players(c, m),
          "<h3>Metrics</h3>",
          '<p class="why">The numbers <code>bowsynth compare</code> prints, each column one pair of signals.</p>',
          _metrics_table(c),
          '<p class="why">What a listener hears (GUIDE section 9), measured by this report:</p>',
          _listener_table(m),
          '<div class="grid2">',
          H.figure(_harmonic_plot(m, plt), "Timbre: each harmonic's level, the file against the reference, over "
                   "the steady part. A bar pair that differs by a dB or more is a colour change you can hear."),
          H.figure(_pitch_plot(m, plt), "Pitch: the note's pitch over time (top) and the file's distance from the "
                   "reference in cents (bottom; green: the audio-rate FDM's, for scale)."),
          "</div>",
          H.figure(_onset_plot(c, m, plt), "Onset: how the note speaks. Left, the waveforms around the onset; right, "
                   "the one-period RMS over the whole note, and when each reaches half its final level."),
          H.figure(_spectrogram_plot(c, m, plt), "Spectrograms side by side on one colour scale: missing or extra "
                   "energy in the upper harmonics shows as a darker or brighter line."),
          "<h3>Scene, engine, model</h3>", f'<div class="card">{_scene_card(c, meta, name)}</div>',
          "</section>"]
    return "\n".join(x for x in s if x)


def _header(title: str, sub: str) -> str:
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    from .. import __version__

    return (f"<h1>{H.esc(title)}</h1><p class=\"sub\">{H.esc(sub)} &middot; bowsynth {H.esc(__version__)} &middot; "
            f"{when}</p>")


def compare_page(c: Comparison, meta: dict | None, name: str) -> str:
    sc = f"scene {c.scene.describe()}, {c.scene.duration:g} s at {c.scene.sample_rate} Hz" if c.scene else ""
    body = [_header(f"Listening report: {name}", f"bowsynth compare {name}" + (f"; {sc}" if sc else "")),
            comparison_section(c, meta, name)]
    return H.page(f"bowsynth report: {name}", "\n".join(body))


def write_compare_report(path, c: Comparison, info, force: bool = False) -> None:
    """The page for one compared file (info: its bowsynth.io.audio.WavInfo)."""
    H.write_page(path, compare_page(c, info.meta, info.path.name), force=force)


def mix_page(mix_path, rows: list, worst: int = 8) -> str:
    """A mix: one table row per note, then a section for each of the `worst` notes with the largest NMSE against the
    reference (the first column compare prints)."""
    from pathlib import Path

    from ..analysis.compare import mix_stems
    from ..io.audio import read_wav
    from ..music.notes import note_name

    mix_path = Path(mix_path)
    d, _ = mix_stems(mix_path)
    first = list(rows[0][1].columns)[0] if rows else ""

    def score(row):
        v = row[1].columns[first].get("nmse")
        return v if isinstance(v, float) and math.isfinite(v) else math.inf

    order = sorted(range(len(rows)), key=lambda i: -score(rows[i]))
    shown = set(order[:max(0, worst)])
    table_rows = []
    for i, (n, c) in enumerate(rows):
        label = f"{n.get('voice', '')} {note_name(n['pitch']) if n.get('pitch') else n['file']}".strip()
        cell = ("html", f'<a href="#note-{i}">{H.esc(label)}</a>') if i in shown else label
        vals = [H.num(c.columns[first].get(k), f) for k, _, f in ROWS if k in ("nmse", "cents", "harmonic_error_db")]
        table_rows.append([cell, f"{n['start']:.3f}", f"{n.get('duration', float('nan')):.3f}", *vals])
    mix = read_wav(mix_path)
    g = H.common_gain(mix.samples)
    body = [_header(f"Listening report: {mix_path.name}",
                    f"a mix of {len(rows)} notes, each compared through its stem ({d.name}/) against the FDM of its "
                    f"own scene"),
            '<h2>The mix</h2><div class="players">' +
            H.player("the mix", f"{mix_path.name} as written (its own gain)", mix.samples, mix.sample_rate, g) +
            "</div>",
            "<h2>Notes</h2>",
            f'<p class="why">Each note against {H.esc(first)}; the {len(shown)} with the largest NMSE have a section '
            f'below (linked; <code>--report-notes N</code> sets how many).</p>',
            H.table(["note", "start (s)", "duration (s)", "NMSE", "pitch error (cents)",
                     "harmonic amplitude error (dB)"], table_rows, {1, 2, 3, 4, 5}, cls="notes")]
    for i in order[:max(0, worst)]:
        n, c = rows[i]
        stem = read_wav(d / n["file"])
        k = None if n.get("duration") is None else int(round(n["duration"] * stem.sample_rate))
        label = f"{n.get('voice', '')} {note_name(n['pitch']) if n.get('pitch') else ''}".strip()
        body.append(comparison_section(c, stem.meta, f"{d.name}/{n['file']}", k, anchor=f"note-{i}",
                                       heading=f"Note {i + 1}: {label} at {n['start']:.3f} s ({n['file']})"))
    return H.page(f"bowsynth report: {mix_path.name}", "\n".join(body))


def write_mix_report(path, mix_path, rows: list, worst: int = 8, force: bool = False) -> None:
    H.write_page(path, mix_page(mix_path, rows, worst), force=force)


def check_report_path(path, plot=None, notes: int = 8, force: bool = False) -> None:
    """Refuse a report path before any work, by the rules of every output (bowsynth.io.outfile), plus: a page to open
    is an .html file, not standard output, and not the --plot file."""
    from ..errors import UsageError
    from ..io.outfile import check_output_path, is_stdout

    if is_stdout(path):
        raise UsageError("--report writes a page to open in a browser; give an .html file, not - (standard output)")
    if path.suffix.lower() not in (".html", ".htm"):
        raise UsageError(f"--report writes an HTML page; give a .html file name, got {path}")
    if plot is not None and str(plot) != "-" and path.resolve() == plot.resolve():
        raise UsageError(f"--report and --plot name the same file ({path})")
    if notes < 0:
        raise UsageError(f"--report-notes must be >= 0, got {notes}")
    check_output_path(path, force=force)
