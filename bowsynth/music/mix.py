"""A performed piece written out: one stem per voice (all or none), the mix, their names and the size checks made
before any work."""

from __future__ import annotations

import json
import os
import re
import secrets
from pathlib import Path

import numpy as np

from ..errors import BowsynthError
from ..render import Played
from .note import Note
from .score import ScoreError


def safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "voice"


def stem_names(notes: list[Note]) -> list[str]:
    """File names of the notes' stems: `voice.wav` for a voice of one note, else `voice-001.wav`, ... in time order
    (voices of the same name, a preset listed twice, get `name-2.wav`, ...)."""
    per_voice: dict[str, list[int]] = {}
    for i, n in enumerate(notes):
        per_voice.setdefault(n.name, []).append(i)
    names = [""] * len(notes)
    seen: dict[str, int] = {}
    for voice, idx in per_voice.items():
        stem = safe_name(voice)
        idx = sorted(idx, key=lambda i: (notes[i].start, i))
        for k, i in enumerate(idx):
            base = stem if len(idx) == 1 else f"{stem}-{k + 1:03d}"
            seen[base] = seen.get(base, 0) + 1
            names[i] = f"{base}.wav" if seen[base] == 1 else f"{base}-{seen[base]}.wav"
    return names


def stem_paths(notes: list[Note], out: Path) -> list[Path]:
    """Every file a stems directory `out` will hold: one WAV per note, then notes.json."""
    return [Path(out) / f for f in stem_names(notes)] + [Path(out) / "notes.json"]


# the longest method, gain, time and model id a stem's metadata can hold: the size check runs before rendering
_WORST_METHOD = str(Played("operator", fdm_fallback=True, fdm_release=True))  # the longest method text
_WORST_FLOAT = 1 / 3
_WORST_MODEL = "x" * 64


def check_stems_fit(notes: list[Note], signal: str = "u", dc: str = "remove") -> None:
    """Before rendering: every note's stem metadata (wav.render_meta, scene and curves included) fits a WAV comment
    (else a one-line ScoreError naming the note)."""
    from ..io.audio import META_LIMIT, render_meta

    for n in notes:
        meta = render_meta(n.scene, _WORST_METHOD, signal, _WORST_FLOAT, _WORST_FLOAT, _WORST_MODEL, dc)
        size = len(json.dumps(meta, separators=(",", ":")))
        if size > META_LIMIT["WAV"]:
            raise ScoreError(f"{n.describe()}: its bow curves are too long to store in a stem's metadata ({size} "
                             f"characters, at most {META_LIMIT['WAV']}); use fewer breakpoints, or write only the mix "
                             f"(--mix without --stems)")


def check_outputs_fit(notes: list[Note], mix: Path | str | None = None, stems: Path | None = None,
                      signal: str = "u", dc: str = "remove") -> None:
    """The one metadata check before rendering: each stem's (when stems are written) and the mix's (when a mix is
    written, in its format: `wav.check_meta_fits`)."""
    from ..io.audio import check_meta_fits

    if stems is not None:
        check_stems_fit(notes, signal, dc)
    if mix is not None:
        from ..io.audio import mix_meta

        check_meta_fits(mix_meta(_voice_names(notes), _WORST_FLOAT, dc, **_mix_extra(notes, mix, stems, signal)), mix)


def _voice_names(notes) -> list[str]:
    return list(dict.fromkeys(n.name for n in notes))


def _mix_extra(notes, out, stems, signal) -> dict:
    """A mix's own metadata fields beside wav.mix_meta's: the note count, the signal and where its stems are."""
    extra = {"notes": len(notes), "signal": signal}
    if stems is not None:  # relative to the mix's directory, so `compare` finds them from the mix
        extra["stems"] = os.path.relpath(Path(stems).resolve(), Path(out).resolve().parent)
    return extra


def write_stems(notes, renders, out: Path, signal: str = "u", dc: str = "remove", gain_db: float | None = None,
                force: bool = True) -> list[Path]:
    """One audio file per note into the directory `out` (each with its own scene, so `compare` reads it; its DC
    removed on its own, as `render` would), and `out/notes.json`: each note's file, voice, start, written duration
    and pitch.

    All or none: the stems are written into a hidden staging directory inside `out` (a Ctrl-C or SIGTERM there
    removes it and leaves `out` as it was), then moved into place by renames with the signals held (a few ms for 150
    stems), notes.json last. A stem path that is a symlink, FIFO or device is written through at that point."""
    import shutil

    from ..io.audio import DC_TAG, write_wav
    from ..errors import held

    out.mkdir(parents=True, exist_ok=True)
    stage = out / f".staging-{os.getpid()}-{secrets.token_hex(3)}"
    stage.mkdir()
    paths, index = [], []
    try:
        for n, r, fname in zip(notes, renders, stem_names(notes)):
            write_wav(stage / fname, r, signal=signal, dc=dc, gain_db=gain_db, force=True)
            paths.append(out / fname)
            index.append({"file": fname, "voice": n.name, "start": n.start, "duration": n.hold, "release": n.release,
                          "pitch": n.pitch, "label": n.describe(), "method": r.method, **n.extra})
        text = json.dumps({"bowsynth_stems": 1, "signal": signal, "dc": DC_TAG if dc == "remove" else "kept",
                           "notes": index}, indent=1)
        (stage / "notes.json").write_text(text + "\n")
        with held():
            for fname in [p.name for p in paths] + ["notes.json"]:
                dst = out / fname
                if dst.is_symlink() or (dst.exists() and not dst.is_file()):
                    with open(stage / fname, "rb") as src, open(dst, "wb") as sink:
                        shutil.copyfileobj(src, sink)
                else:
                    os.replace(stage / fname, dst)
    except OSError as e:
        raise BowsynthError(f"could not write the stems into {out}: {e.strerror or e}") from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return paths


def mix_notes(notes, renders, signal: str = "u") -> tuple[np.ndarray, int]:
    """The notes summed, each placed at its start sample (as rendered: the DC is removed once, from the sum, by
    `wav.write_mix`). A displacement is mixed as q = w u (the same waveform), so a note's loudness does not grow
    with its period; velocity p is mixed as is."""
    rates = {r.scene.sample_rate for r in renders}
    if len(rates) != 1:
        raise ScoreError(f"a mix needs one sample rate; the notes use {sorted(rates)}")
    rate = rates.pop()
    starts = [int(round(n.start * rate)) for n in notes]
    x = np.zeros(max(s + len(r.q) for s, r in zip(starts, renders)))
    for s, r in zip(starts, renders):
        sig = r.q if signal == "u" else r.signal(signal)
        x[s:s + len(sig)] += sig  # float32 notes cast in the add: a float64 copy of each took a third of the mix
    return x, rate


def write_voices(voices, renders, out: Path, mix: bool, signal: str = "u", stems: Path | None = None,
                 dc: str = "remove", gain_db: float | None = None, force: bool = True) -> list[Path]:
    """Stems (one file per note) into the directory `out`, or (mix=True) the mix into the file `out` (and, with
    `stems`, the stems into that directory; the mix's metadata points to them for `compare`).

    DC (dc='remove'): each stem is filtered on its own, and the mix is the sum of the unfiltered notes at their
    starts, filtered once. The filter (wav.remove_dc) is zero-phase with a mean subtraction, so it does not commute
    with placing notes at other starts: the mix equals remove_dc(sum of the notes as rendered), not the sum of the
    filtered stems (tests/test_midi.py checks the first exactly)."""
    from ..io.audio import write_mix

    if not mix:
        return write_stems(voices, renders, out, signal, dc=dc, gain_db=gain_db, force=force)
    paths = []
    if stems is not None:
        paths += write_stems(voices, renders, stems, signal, dc=dc, gain_db=gain_db, force=force)
    x, rate = mix_notes(voices, renders, signal)
    write_mix(out, x, _voice_names(voices), rate, dc=dc, gain_db=gain_db, force=force,
              **_mix_extra(voices, out, stems, signal))
    return [out] + paths
