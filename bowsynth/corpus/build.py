"""Render a corpus: the spec's notes in batches (one batched rollout each), on Ray or in this process, into the
audiofolder layout Hugging Face `datasets` loads with no code of ours:

    DIR/metadata.jsonl        one JSON object per note: file_name (data/NNNNNNN.wav), its labels, reference_file_name
    DIR/data/NNNNNNN.wav      the operator's note, as `render` writes it (32-bit float, the scene in its comment)
    DIR/reference/NNNNNNN.wav --with-reference: the x100 FDM of the same scene
    DIR/spec.json             the spec it was drawn from: a rerun with another spec is refused

    datasets.load_dataset("audiofolder", data_dir=DIR)   # columns audio, reference, and the labels

Resumable: the metadata lists exactly the notes whose files are whole (each written to a temporary name and renamed,
the metadata rewritten the same way after every batch), so an interrupted run leaves a corpus that loads, and a
rerun renders only what is missing.
"""

from __future__ import annotations

import functools
import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from ..errors import UsageError
from .spec import NoteSpec, Spec, SpecError, draw_note

BATCH = 16  # notes per task: one batched rollout
META = "metadata.jsonl"
HEADROOM = 1.1  # the disk estimate's margin


@dataclass
class Built:
    written: int
    kept: int
    total: int
    seconds: float
    interrupted: bool = False
    note: str = ""


def _playable(note: NoteSpec) -> bool:
    """Does the bow sound (the map's ratio) and does a validated model cover the note (never the reference)?"""
    from ..engines.operator.choose import covering_model
    from ..music.ratio_map import physics_ratio
    from ..scene import Scene

    try:
        physics_ratio(note.beta, max(note.vb_held, 1e-9), 100.0)
        sc = Scene(f0=note.f0, fb=note.fb, vb=note.vb, duration=1.0)
    except Exception:  # noqa: BLE001 - a bow that does not sound, or a scene out of range: drawn again
        return False
    return covering_model(sc) is not None


def plan(spec: Spec) -> list[NoteSpec]:
    return [draw_note(spec, i, _playable) for i in range(spec.count)]


def note_bytes(spec: Spec, reference: bool) -> int:
    """The disk a note takes: its float32 samples, the comment, the metadata line; twice the audio with a reference."""
    audio = int(spec.duration * spec.sample_rate) * 4 + 4096
    return audio * (2 if reference else 1) + 512


def check_disk(out: Path, spec: Spec, reference: bool, missing: int) -> None:
    need = int(missing * note_bytes(spec, reference) * HEADROOM)
    probe = out if out.exists() else out.parent
    free = shutil.disk_usage(probe if str(probe) else ".").free
    if need > free:
        raise UsageError(f"{missing} notes need about {need / 1e9:.3g} GB and {probe} has {free / 1e9:.3g} GB free: "
                         f"lower count or duration, or write elsewhere")


def _render_batch(job):
    """A task: render the notes (one batched rollout with the operator; the x100 FDM too with a reference) and
    return per note its samples and its metadata row; on this machine (`here`, the corpus's directory) it writes the
    files itself and returns the rows alone, else the driver writes them (a cluster's nodes share no disk). A note whose rollout leaves
    its model's trained states is finished by the FDM (--fallback fdm) and labelled so ('operator+fdm')."""
    from .. import api
    from ..io.audio import wav_payload
    from ..scene import Scene

    notes, spec, reference, here = job
    scenes = [Scene(f0=n.f0, fb=n.fb, vb=n.vb, duration=spec.duration, sample_rate=spec.sample_rate) for n in notes]
    renders = api.render(scenes, fallback="fdm")
    out = []
    for n, sc, r in zip(notes, scenes, renders):
        x, meta = wav_payload(r)
        ref = None
        if reference:
            ref = wav_payload(api.render_fdm(sc, oversample=100))
        row = _labels(n, spec, str(r.method), r.info.model_path, reference)
        if here is not None:  # a worker of this machine writes the files itself: the driver only lists them
            _write_note(Path(here), n, spec, x, meta, ref)
            x = meta = ref = None
        out.append((n, x, meta, ref, row))
    return out


def _write_note(out: Path, n: NoteSpec, spec: Spec, x, meta, ref) -> None:
    from ..io.audio import write_float_wav

    write_float_wav(out / "data" / f"{n.name}.wav", x, spec.sample_rate, meta)
    if ref is not None:
        write_float_wav(out / "reference" / f"{n.name}.wav", ref[0], spec.sample_rate, ref[1])


def _labels(n: NoteSpec, spec: Spec, method: str, model_path, reference: bool) -> dict:
    from ..music.ratio_map import physics_ratio

    try:
        pitch = n.f0 * physics_ratio(n.beta, n.vb_held, 100.0).r
    except Exception:  # noqa: BLE001 - a gesture's held bow at a stop: no sounding pitch to label
        pitch = math.nan
    row = {"file_name": f"data/{n.name}.wav", "index": n.index, "kind": n.kind, "f0": n.f0,
           "fb": json.dumps(n.fb), "vb": json.dumps(n.vb), "beta": n.beta, "vb_held": n.vb_held,
           "pitch": None if not math.isfinite(pitch) else pitch, "duration": spec.duration,
           "sample_rate": spec.sample_rate, "engine": method,
           "model": Path(model_path).stem if model_path else "", "accuracy": _accuracy(model_path)}
    if reference:
        row["reference_file_name"] = f"reference/{n.name}.wav"
    return row


@functools.lru_cache(maxsize=256)
def _accuracy(model_path) -> str:
    """The playing model's validation, as `bowsynth models` states it (read once per model and process)."""
    if not model_path:
        return ""
    from ..engines.operator.choose import as_model
    from ..engines.operator.modelfile import validation_failure

    m = as_model(model_path)
    v = m.meta.validation or {}
    fail = validation_failure(m.meta)
    if fail:
        return f"failed: {fail}"
    parts = [f"{name} {v[k]:.3g}" for k, name in (("harm_db_median", "harmonics dB median"),
                                                  ("cents_abs_max", "pitch cents worst"), ("nmse", "NMSE"))
             if isinstance(v.get(k), (int, float))]
    return ", ".join(parts)


def _whole(path: Path, frames: int) -> bool:
    import soundfile as sf

    try:
        return sf.info(str(path)).frames == frames
    except Exception:  # noqa: BLE001 - unreadable: not whole
        return False


def _write_meta(out: Path, rows: dict) -> None:
    from ..io.outfile import atomic_write

    text = "".join(json.dumps(rows[i], allow_nan=False) + "\n" for i in sorted(rows))
    atomic_write(out / META, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def _existing(out: Path, spec: Spec, reference: bool) -> dict:
    """The metadata rows of notes whose files are whole (index -> row)."""
    rows = {}
    meta = out / META
    if not meta.is_file():
        return rows
    frames = int(round(spec.duration * spec.sample_rate))
    for line in meta.read_text(encoding="utf-8").splitlines():
        try:
            row = json.loads(line)
            i = int(row["index"])
        except (ValueError, KeyError, TypeError):
            continue
        ok = _whole(out / row["file_name"], frames)
        if reference:
            ok = ok and "reference_file_name" in row and _whole(out / row["reference_file_name"], frames)
        if ok and 0 <= i < spec.count:
            rows[i] = row
    return rows


def _claim(out: Path, spec: Spec) -> None:
    """The directory holds this spec's corpus (or nothing yet); another spec's is refused."""
    from ..io.outfile import atomic_write

    out.mkdir(parents=True, exist_ok=True)
    (out / "data").mkdir(exist_ok=True)
    mine = json.dumps(spec.to_dict(), sort_keys=True)
    sj = out / "spec.json"
    if sj.exists():
        try:
            theirs = json.dumps(json.loads(sj.read_text(encoding="utf-8")), sort_keys=True)
        except (OSError, ValueError):
            theirs = None
        if theirs != mine:
            raise SpecError(f"{out} holds a corpus of another spec (its spec.json): give a new directory")
    else:
        atomic_write(sj, lambda tmp: Path(tmp).write_text(mine + "\n", encoding="utf-8"))


def build(spec: Spec, out, workers: int = 1, address: str | None = None, reference: bool = False,
          progress=None) -> Built:
    """Render what is missing of the spec's corpus into `out`; progress(done, total, eta_seconds) after each batch.
    Ctrl-C (or SIGTERM) stops after the files written so far, which the metadata lists."""
    from ..errors import Terminated
    from ..io.cluster import Pool

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out} is not a directory")
    t0 = time.monotonic()
    probe_rows = _existing(out, spec, reference) if out.is_dir() else {}
    check_disk(out, spec, reference, spec.count - len(probe_rows))  # before drawing a note
    _claim(out, spec)
    missing = [n for n in plan(spec) if n.index not in probe_rows]
    if reference:
        (out / "reference").mkdir(exist_ok=True)
    rows = dict(probe_rows)
    _write_meta(out, rows)  # only whole files listed, from the start
    written, interrupted = 0, False
    pool = Pool(workers, address)
    here = str(out.resolve()) if pool.address is None else None  # workers of this machine write their own files
    jobs = [(missing[a:a + BATCH], spec, reference, here) for a in range(0, len(missing), BATCH)]
    try:
        for _, results in pool.map(_render_batch, jobs):
            for n, x, meta, ref, row in results:
                if x is not None:
                    _write_note(out, n, spec, x, meta, ref)
                rows[n.index] = row
                written += 1
            _write_meta(out, rows)
            if progress is not None:
                el = time.monotonic() - t0
                progress(len(rows), spec.count, el / written * (len(missing) - written) if written else math.nan)
    except (KeyboardInterrupt, Terminated):
        interrupted = True
    finally:
        pool.close()
        _write_meta(out, rows)
    return Built(written, len(probe_rows), spec.count, time.monotonic() - t0, interrupted, pool.note)


def loadable_columns(out) -> list[str]:
    """The columns `datasets` gives the corpus (audio, reference where written, and the labels)."""
    first = (Path(out) / META).read_text(encoding="utf-8").splitlines()[0]
    cols = list(json.loads(first))
    return ["audio" if c == "file_name" else c.removesuffix("_file_name") if c.endswith("_file_name") else c
            for c in cols]

