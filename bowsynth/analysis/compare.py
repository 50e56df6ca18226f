"""Compare a rendered WAV against the FDM (audio rate, optionally a high-rate ground truth) or another WAV."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..engines.fdm import TRUTH_OVERSAMPLE, render_fdm
from ..errors import UsageError
from ..io.audio import DC_HZ, read_wav, remove_dc
from ..scene import Scene
from ..io.text import jsonable, num
from ..metrics import EQUAL_OVERSAMPLES, compare_signals


@dataclass
class Comparison:
    """Metrics of each compared signal against each reference, plus the render times."""

    scene: Scene | None
    signal: str
    columns: dict = field(default_factory=dict)  # label -> metrics dict
    seconds: dict = field(default_factory=dict)  # label -> render wall time
    series: dict = field(default_factory=dict, repr=False)  # label -> signal, for plots
    notes: list = field(default_factory=list)  # what a reader of the scores must know (lossy file, DC handling)
    # the cheapest FDM as accurate as the file against the truth (metrics.as_accurate): oversample (None: none of
    # those tried), seconds (its render time, or the costliest tried), accuracy of the file and of that FDM
    equal: dict | None = None

    def to_json(self) -> dict:
        speed = equal = None
        a, f = self.seconds.get("file"), self.seconds.get("fdm")
        if a and f:
            speed = f / a
        if a and self.equal:
            equal = {**self.equal, "ratio": self.equal["seconds"] / a}
        return {"scene": self.scene.to_dict() if self.scene else None, "signal": self.signal,
                "metrics": jsonable(self.columns),
                "render_seconds": self.seconds, "speed_ratio_fdm_over_file": speed,
                "speed_at_equal_accuracy": jsonable(equal), "notes": self.notes}


def _fdm_signal(scene: Scene, signal: str, oversample: int, dc_removed: bool):
    """The FDM reference as the file would hold it: with the DC removed exactly as the file's was (the same
    deterministic filter), so the scores compare the physics and not the filter."""
    r = render_fdm(scene, oversample=oversample)
    x = r.signal(signal)
    return (remove_dc(x, scene.sample_rate) if dc_removed else x), r.seconds


def dc_settle(n: int, sample_rate: float) -> int:
    """The samples scored of n whose DC was removed: all but the last 1 / DC_HZ seconds, where the filter's backward
    pass starts up (remove_dc pads the end by odd reflection, whose mean differs from the signal's by twice where the
    last period ended, and the 5 Hz high-pass takes ~1 / DC_HZ to forget that). Two FDM renders of the paper's
    F_B 1000 note, 3 s and 3.005-3.025 s long, the same physics, read -8.3 to +0.5 cents apart with the ends scored
    (the zero crossings of u there move by up to a third of a period), within 0.05 cents without them. Signals
    shorter than three times that keep every sample."""
    settle = int(round(sample_rate / DC_HZ))
    return n - settle if n > 3 * settle else n


DC_SETTLE_NOTE = ("the last {:g} s of each signal, where the DC filter starts up, are not scored (the filter would "
                  "move each signal's zero crossings there)")


def _lossy_notes(*infos) -> list[str]:
    return [f"{i.path.name} is {i.format} (lossy): the scores include the codec's error, not only the render's"
            for i in infos if i.lossy]


def compare_wav(path, other=None, scene: Scene | None = None, reference: str = "high",
                pitch_seconds: float | None = None, force: bool = False, equal: bool = True) -> Comparison:
    """Compare the audio file at `path` with the FDM render of its scene (from its metadata, curves included, else
    `scene`), or with the file `other`.

    reference='high' (default): first against a x100 FDM, the truth, then against the audio-rate FDM (what a user
    would otherwise run) and that FDM against the truth; 'audio': the audio-rate FDM only (fast, but at high pitch
    and force it is the less accurate of the two). pitch_seconds: measure the pitch on the steady half of the first
    seconds only (a note's sustain, before its bow stop). equal (reference 'high'): find the cheapest FDM (x1, x2,
    ... x32) as accurate as the file against the truth, for the speed row. Every FDM reference gets the file's DC
    treatment. FDM references estimated past a couple of minutes are refused unless force=True."""
    from ..engines.limits import check_fdm

    if reference not in ("audio", "high"):
        raise UsageError(f"--reference must be audio or high, got {reference!r}")
    a = read_wav(path)
    if other is not None:
        b = read_wav(other)
        if a.sample_rate != b.sample_rate:
            raise UsageError(f"sample rates differ: {a.sample_rate} Hz and {b.sample_rate} Hz")
        n = min(len(a.samples), len(b.samples))
        if n == 0:
            raise UsageError(f"{(a if not len(a.samples) else b).path.name} holds no samples: nothing to compare")
        x, y = a.physical, b.physical
        notes = _lossy_notes(a, b)
        if a.dc_removed != b.dc_removed:  # filter the one that kept its DC, so the DC does not count as error
            kept = b if a.dc_removed else a
            notes.append(f"{kept.path.name} kept its DC; the same 5 Hz high-pass was applied to it before scoring")
            x, y = (x, remove_dc(y, b.sample_rate)) if a.dc_removed else (remove_dc(x, a.sample_rate), y)
        x, y = x[:n], y[:n]
        s = dc_settle(n, a.sample_rate) if a.dc_removed or b.dc_removed else n  # the samples scored
        if s < n:
            notes.append(DC_SETTLE_NOTE.format(round((n - s) / a.sample_rate, 3)))
        c = Comparison(a.scene or b.scene, (a.meta or b.meta or {}).get("signal", "u"), notes=notes)
        c.columns[f"{a.path.name} vs {b.path.name}"] = compare_signals(x[:s], y[:s], a.sample_rate)
        c.seconds = {"file": (a.meta or {}).get("render_seconds"), "other": (b.meta or {}).get("render_seconds")}
        c.series = {a.path.name: x, b.path.name: y}
        return c
    sc = a.scene or scene
    if sc is None:
        mix = mix_meta(a.path)
        if mix is not None:
            raise UsageError(_mix_hint(a.path, mix))
        raise UsageError(f"{a.path} has no bowsynth metadata; give the scene with --fb/--vb/--f0/... flags")
    if a.sample_rate != sc.sample_rate:
        raise UsageError(f"{a.path} is at {a.sample_rate} Hz but its scene says {sc.sample_rate} Hz")
    sig = (a.meta or {}).get("signal", "u")
    check_fdm(sc, 1, force, "the FDM reference")
    if reference == "high":
        check_fdm(sc, TRUTH_OVERSAMPLE, force, f"the x{TRUTH_OVERSAMPLE} FDM reference")
    x = a.physical
    fdm, fdm_s = _fdm_signal(sc, sig, 1, a.dc_removed)
    if not np.any(fdm):  # e.g. v_B = 0 from rest: no metric has anything to measure against
        raise UsageError(f"the FDM render of this scene is silent ({sc.describe()}): there is nothing to compare "
                         f"{a.path.name} against")
    n = min(len(x), len(fdm))
    x, fdm = x[:n], fdm[:n]
    c = Comparison(sc, sig, notes=_lossy_notes(a))
    s = n  # the samples scored (the series keep all n, for the plots and the players)
    if a.dc_removed:
        c.notes.append("the file's DC was removed (5 Hz high-pass); the FDM references were filtered the same way")
        s = dc_settle(n, sc.sample_rate)
        if s < n:
            c.notes.append(DC_SETTLE_NOTE.format(round((n - s) / sc.sample_rate, 3)))
    c.seconds = {"file": (a.meta or {}).get("render_seconds"), "fdm": fdm_s}
    c.series = {"file": x, "FDM": fdm}
    k = s if pitch_seconds is None else max(4, min(s, int(round(pitch_seconds * sc.sample_rate))))

    def cmp(u, v):
        return compare_signals(u[:s], v[:s], sc.sample_rate, pitch_signal_x=u[:k], pitch_signal_ref=v[:k])

    if reference == "high":
        hi, hi_s = _fdm_signal(sc, sig, TRUTH_OVERSAMPLE, a.dc_removed)
        hi = hi[:n]
        c.columns[f"file vs FDM x{TRUTH_OVERSAMPLE} (truth)"] = cmp(x, hi)
        c.columns["file vs FDM"] = cmp(x, fdm)
        c.columns[f"FDM vs FDM x{TRUTH_OVERSAMPLE}"] = cmp(fdm, hi)
        c.seconds[f"fdm_x{TRUTH_OVERSAMPLE}"] = hi_s
        c.series[f"FDM x{TRUTH_OVERSAMPLE}"] = hi
        if equal:
            c.equal = _equal_fdm(sc, sig, a.dc_removed, x[:s], hi[:s], (fdm, fdm_s))
            c.notes.append("speed at equal accuracy: the render time of the cheapest FDM (x1, x2, ... x"
                           f"{EQUAL_OVERSAMPLES[-1]}) whose harmonics (median dB), pitch (cents) and NMSE against the "
                           "truth are each at most the file's, over the file's own render time")
    else:
        c.columns["file vs FDM"] = cmp(x, fdm)
    return c


def _equal_fdm(sc: Scene, sig: str, dc_removed: bool, x, truth, first) -> dict:
    """The cheapest FDM of EQUAL_OVERSAMPLES as accurate as x against the truth: the audio-rate render is `first`
    (signal, seconds), the others are rendered here until one is as accurate."""
    from ..metrics import accuracy, as_accurate

    want = accuracy(x, truth, sc.sample_rate)
    n = len(truth)
    for os_ in EQUAL_OVERSAMPLES:
        y, secs = first if os_ == 1 else _fdm_signal(sc, sig, os_, dc_removed)
        got = accuracy(y[:n], truth, sc.sample_rate)
        if as_accurate(got, want):
            return {"oversample": os_, "seconds": secs, "file": want, "fdm": got}
    return {"oversample": None, "seconds": secs, "file": want, "fdm": got}


def mix_meta(path) -> dict | None:
    """The metadata of a mix written by `bowsynth score --mix` (None for any other file)."""
    import json

    import soundfile as sf

    try:
        with sf.SoundFile(str(path)) as f:
            m = json.loads(f.comment or "null")
    except (RuntimeError, ValueError, sf.LibsndfileError):
        return None
    return m if isinstance(m, dict) and m.get("bowsynth_mix") else None


def _mix_hint(path, mix: dict) -> str:
    return (f"{path} is a mix of {mix.get('notes', 'several')} notes; a note cannot be cut out of the sum where notes "
            f"overlap, so it is compared through its stems: render it again with `bowsynth score ... --mix {path} "
            f"--stems DIR` and compare {path} (or each DIR/*.wav)")


def mix_stems(path) -> tuple[Path, list[dict]]:
    """The stems directory of a mix and its notes (from notes.json), or a UsageError saying why there are none."""
    import json

    p = Path(path)
    mix = mix_meta(p)
    if mix is None:
        raise UsageError(f"{p} is not a bowsynth mix")
    if not mix.get("stems"):
        raise UsageError(_mix_hint(p, mix))
    d = (p.resolve().parent / mix["stems"]).resolve()
    index = d / "notes.json"
    if not index.is_file():
        raise UsageError(f"the stems of {p} are gone (no {index}); render the mix again with --stems")
    try:
        notes = json.loads(index.read_text())["notes"]
        files = [d / str(n["file"]) for n in notes]
        for n in notes:  # the fields the comparison reads, of the types score writes (an edited index is refused)
            for key in ("start", "duration"):
                if key in n and not (isinstance(n[key], (int, float)) and not isinstance(n[key], bool)
                                     and math.isfinite(n[key]) and n[key] >= 0):
                    raise ValueError(f"{key} {n[key]!r}")
            if n.get("pitch") is not None and not (isinstance(n["pitch"], (int, float)) and n["pitch"] > 0):
                raise ValueError(f"pitch {n['pitch']!r}")
            if "/" in str(n["file"]) or str(n["file"]).startswith("."):
                raise ValueError(f"file {n['file']!r} is not a stem's name")
    except (ValueError, KeyError, TypeError, RecursionError):
        raise UsageError(f"{index} is damaged; render the mix again with --stems") from None
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise UsageError(f"stems of {p} missing in {d}: {', '.join(missing[:5])}")
    return d, notes


def compare_mix(path, reference: str = "high", force: bool = False) -> list[tuple[dict, Comparison]]:
    """Each note of a mix (through the stems written beside it) against the FDM of its own scene, the pitch
    measured over the note's sustain. Each stem's references get that stem's DC treatment (compare_wav)."""
    d, notes = mix_stems(path)
    return [(n, compare_wav(d / n["file"], reference=reference, pitch_seconds=n.get("duration"), force=force,
                            equal=False)) for n in notes]


MIX_ROWS = [("nmse", "NMSE", "{:.3g}"), ("cents", "cents", "{:+.3f}")]


def format_mix_table(rows: list[tuple[dict, Comparison]]):
    """One row per note: the file against the truth (x100 FDM) and, beside, against the audio-rate FDM."""
    from rich.table import Table

    from ..music.notes import note_name

    labels = list(rows[0][1].columns) if rows else []
    short = dict(zip(labels[:2], ["x100", "FDM"] if len(labels) > 1 else ["FDM"]))
    t = Table(title=f"each note against the FDM of its own scene (x100: the FDM at {TRUTH_OVERSAMPLE}x the rate, the "
                    f"truth; FDM: at the file's rate)")
    t.add_column("note")
    t.add_column("start s", justify="right")
    for label in short:
        for _, name, _ in MIX_ROWS:
            t.add_column(f"{name} vs {short[label]}", justify="right")
    for n, c in rows:
        vals = []
        for label in short:
            d = c.columns[label]
            for key, _, fmt in MIX_ROWS:
                v = d.get(key)
                vals.append(num(v, fmt))
        name = f"{n.get('voice', '')} {note_name(n['pitch']) if n.get('pitch') else n['file']}"
        t.add_row(name, f"{n['start']:.3f}", *vals)
    return t


ROWS = [("nmse", "NMSE", "{:.3g}"), ("ncc_percent", "NCC (%)", "{:.4f}"), ("f0_hz", "f0 (Hz)", "{:.4f}"),
        ("f0_ref_hz", "f0 of reference (Hz)", "{:.4f}"), ("cents", "pitch error (cents)", "{:+.3f}"),
        ("harmonic_error_db", "harmonic amplitude error (dB)", "{:.3f}"),
        ("lsd_db", "log-spectral distance (dB)", "{:.3f}")]


def format_table(c: Comparison):
    from rich.table import Table

    t = Table(title=f"signal {c.signal}" + (f", scene {c.scene.describe()} {c.scene.duration:g} s" if c.scene else ""))
    t.add_column("metric")
    for label in c.columns:
        t.add_column(label, justify="right")
    for key, name, fmt in ROWS:
        vals = []
        for d in c.columns.values():
            v = d.get(key)
            vals.append(num(v, fmt))
        t.add_row(name, *vals)
    for label, s in c.seconds.items():
        if s is not None:
            t.add_row(f"render time, {label} (s)", f"{s:.4f}", *[""] * (len(c.columns) - 1))
    j = c.to_json()
    pad = [""] * (len(c.columns) - 1)
    if j["speed_ratio_fdm_over_file"]:
        t.add_row("speed: audio-rate FDM / file", f"{j['speed_ratio_fdm_over_file']:.2f}x", *pad)
    e = j["speed_at_equal_accuracy"]
    if e:
        what = f"FDM x{e['oversample']}" if e["oversample"] else f"FDM x{EQUAL_OVERSAMPLES[-1]}, not yet as accurate"
        t.add_row(f"speed at equal accuracy: {what} / file", f"{'>= ' if not e['oversample'] else ''}{e['ratio']:.2f}x",
                  *pad)
    return t


def plot_comparison(c: Comparison, path, sample_rate: int) -> None:
    """Waveform overlays (onset, steady state), the error over time and both spectrograms, as one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.audio import atomic_write

    labels = list(c.series)
    x, ref = c.series[labels[0]], c.series[labels[-1] if len(labels) < 3 else labels[2]]
    ref_label = labels[-1] if len(labels) < 3 else labels[2]
    t = np.arange(len(x)) / sample_rate
    span = min(len(x), int(0.04 * sample_rate))
    fig, ax = plt.subplots(3, 2, figsize=(12, 10))
    for axis, sl, title in ((ax[0, 0], slice(0, span), "onset"), (ax[0, 1], slice(len(x) - span, len(x)), "steady state")):
        axis.plot(t[sl], ref[sl], "k-", lw=2, alpha=0.5, label=ref_label)
        axis.plot(t[sl], x[sl], "r--", lw=1, label=labels[0])
        axis.set_title(f"{title} ({c.signal})")
        axis.set_xlabel("t (s)")
        axis.legend(loc="upper right", fontsize=8)
    floor = 1e-12 * (np.max(np.abs(ref)) + 1e-300)  # float32 storage puts exact agreement around here
    err = np.maximum(np.abs(x - ref), floor)
    ax[1, 0].semilogy(t, err, lw=0.5)
    ax[1, 0].set_title(f"|{labels[0]} - {ref_label}|")
    ax[1, 0].set_xlabel("t (s)")
    block = max(1, sample_rate // 100)
    nb = len(x) // block
    if nb > 1:
        e = np.sqrt(np.mean((x[:nb * block] - ref[:nb * block]).reshape(nb, block) ** 2, axis=1))
        ax[1, 1].semilogy(t[:nb * block:block], e / (np.std(ref) + 1e-300))
    ax[1, 1].set_title("RMS error per 10 ms / std(reference)")
    ax[1, 1].set_xlabel("t (s)")
    nfft = min(4096, max(64, len(x) // 8))
    images, top = [], -np.inf
    for axis, sig, title in ((ax[2, 0], x, labels[0]), (ax[2, 1], ref, ref_label)):
        spec, _, _, im = axis.specgram(sig, NFFT=nfft, Fs=sample_rate, noverlap=nfft // 2, cmap="magma")
        images.append(im)
        top = max(top, 10 * np.log10(spec.max() + 1e-300))
    for im in images:  # one colour scale for both, so a difference shows as a difference
        im.set_clim(top - 100, top)
    for axis, title in ((ax[2, 0], labels[0]), (ax[2, 1], ref_label)):
        axis.set_ylim(0, min(sample_rate / 2, 4000))
        axis.set_title(f"spectrogram: {title}")
        axis.set_xlabel("t (s)")
        axis.set_ylabel("Hz")
    fig.tight_layout()
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=80, format="png"))
    plt.close(fig)
