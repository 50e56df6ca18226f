"""`bowsynth compare X --report R.html`: the comparison `compare` already computed, made audible and visible.

Everything here is drawn from a Comparison (bowsynth.analysis.compare): its series are the file and the references compare
rendered, so no reference is computed twice. A mix gets a table of its notes and a section for each of its worst
notes (through the stems, as compare_mix measures them)."""

from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np

from ..analysis.compare import ROWS, Comparison
from ..metrics import onset_time
from ..engines.fdm import TRUTH_OVERSAMPLE
from . import html as H
from . import listen as L
from .plots import harmonic_plot, onset_plot, pitch_plot, spectrogram_plot

TRUTH = f"FDM x{TRUTH_OVERSAMPLE}"

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
    """The report's own measures (docs/measures.md) of the file and the audio-rate FDM against the reference: harmonic
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
                f'<p class="note">No x{TRUTH_OVERSAMPLE} FDM here (--reference audio or two files): the reference is '
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
          '<p class="why">What a listener hears (docs/measures.md), measured by this report:</p>',
          _listener_table(m),
          '<div class="grid2">',
          H.figure(harmonic_plot(m, plt), "Timbre: each harmonic's level, the file against the reference, over "
                   "the steady part. A bar pair that differs by a dB or more is a colour change you can hear."),
          H.figure(pitch_plot(m, plt), "Pitch: the note's pitch over time (top) and the file's distance from the "
                   "reference in cents (bottom; green: the audio-rate FDM's, for scale)."),
          "</div>",
          H.figure(onset_plot(c, m, plt), "Onset: how the note speaks. Left, the waveforms around the onset; right, "
                   "the one-period RMS over the whole note, and when each reaches half its final level."),
          H.figure(spectrogram_plot(c, m, plt), "Spectrograms side by side on one colour scale: missing or extra "
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
