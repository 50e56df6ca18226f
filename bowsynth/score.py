"""Scores: notes in time, from a TOML score (docs/score.md), a MIDI file (`bowsynth.midi`) or a list of presets,
rendered in one batched rollout and mixed with each note at its start.

    # score.toml (docs/score.md has the whole format)
    a4 = 440.0
    [defaults]
    beta = 0.15915494     # F_B / w, so one model plays every pitch (or fb = 100.0, a fixed force)
    vb = 0.2
    release = 0.05        # the bow slows to a stop over 50 ms after each note's duration
    [[voice]]
    name = "melody"
    [[voice.note]]
    start = 0.0
    duration = 0.5
    pitch = "A4"
    [[voice.note]]
    start = 0.5
    duration = 1.0
    pitch = "C#5"
    vb = [[0.0, 0.15], [0.8, 0.25]]   # a gesture: times from the note's start

A note is its own bowed mass from rest; a voice is a name for a group of notes (one stem), and its notes may
overlap. The end of a note is a physical bow stop: v_B falls linearly to 0 over `release` seconds, the friction
(its slope is positive below v_B = 1/sqrt(2a)) damps the mass, and the render stops TAIL s later. A note's sustain
is rendered by the chosen engine; its release by the FDM from the sustain's state at the hold (no model covers a bow
slowing to rest; with the operator all releases run as one numpy FDM batch, `finish_releases`), so a note ends the
same way with either engine.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import physics
from .controls import Curve, as_control
from .errors import BowsynthError, DomainError, SceneError, UsageError
from .render import Render
from .scene import Scene, load_preset

RELEASE = 0.05  # s: default bow-stop time
TAIL = 0.03  # s: the shortest render after the bow stops
TAIL_TIME_CONSTANTS = 10.0  # e^-10 by the linear rate; the saturated friction of the first ms is slower
MAX_TAIL = 2.0
MAX_RELEASE = 10.0


def stop_tail(fb: float, f0: float, a: float) -> float:
    """Seconds to render after the bow has stopped (v_B = 0) for the mass to come to rest (-60 dB).

    On a stopped bow the friction is a damper of rate c = F_B phi'(0): the mass rings down at c / 2 when c < 2w;
    above that it creeps back to rest at the slow root (c - sqrt(c^2 - 4 w^2)) / 2 (a pressed bow holds the mass
    aside: measured at F_B / w 0.64, C2, 19 % of the peak was left 30 ms after the stop)."""
    c = fb * physics.dphi(0.0, a)
    if c <= 0:
        return MAX_TAIL
    w = physics.omega(f0)
    rate = 0.5 * (c - math.sqrt(max(c * c - 4 * w * w, 0.0)))
    return float(min(MAX_TAIL, max(TAIL, TAIL_TIME_CONSTANTS / rate)))

TOP_KEYS = {"defaults": "table of note defaults", "voice": "array of voice tables", "a4": "tuning, Hz",
            "title": "text"}
NOTE_KEYS = {"start", "duration", "pitch", "f0", "fb", "beta", "vb", "a", "release", "preset", "sample_rate",
             "q0", "p0", "cents"}
VOICE_KEYS = NOTE_KEYS | {"name", "note"}
DEFAULT_KEYS = NOTE_KEYS - {"start"}
EXCLUSIVE = (("pitch", "f0"), ("fb", "beta"))


class ScoreError(UsageError):
    """A score (TOML or MIDI) that cannot be played as written."""


@dataclass
class Note:
    """One note: its own bowed mass from rest, starting `start` s into the piece.

    `scene` is the whole note (its sustain of `hold` s, then the bow stop of `release` s and the tail); `name` is
    its voice. `pitch` is the asked pitch in Hz (None for a note given by f0)."""

    name: str
    scene: Scene
    start: float = 0.0
    hold: float | None = None
    release: float = 0.0
    pitch: float | None = None
    label: str = ""
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.hold is None:
            self.hold = self.scene.duration

    @property
    def end(self) -> float:
        return self.start + self.scene.duration

    @property
    def gesture(self) -> bool:
        """Does the bow change during the sustain (before the release)?"""
        return self.sustain_scene().varying

    def sustain_scene(self, extra_samples: int = 0) -> Scene:
        """The note without its release: the controls over [0, hold], constant ones as numbers."""
        sc = self.scene
        n = self.hold_samples + extra_samples
        # a moving pitch keeps its force curve (F_B = beta w(t) follows the pitch through the note)
        fb = sc.fb if sc.pitch_varies else _clip(sc.fb, self.hold)
        return sc.replace(fb=fb, vb=_clip(sc.vb, self.hold), duration=n / sc.sample_rate)

    @property
    def hold_samples(self) -> int:
        return int(round(self.hold * self.scene.sample_rate))

    def rollout_scene(self) -> Scene:
        """What the operator plays: the sustain, its bow held to the note's end when there is a release (the release
        then overwrites the samples after the hold in place: copying a 60 s voice into a new array cost more than
        rolling the sustain on through its release)."""
        return self.sustain_scene(self.scene.n_samples - self.hold_samples if self.release > 0 else 0)

    def describe(self) -> str:
        return self.label or self.name


# legacy name: a voice of the round-1 format is one note from 0
Voice = Note


def _clip(control, end: float):
    """A control over [0, end] only (what it does after `end` dropped), as a number if constant there."""
    if not isinstance(control, Curve):
        return control
    t = np.concatenate([[0.0], control.times[(control.times > 0) & (control.times < end)], [end]])
    pts = [(float(a), float(b)) for a, b in zip(t, control.at(t))]
    dedup = [pts[0]] + [p for prev, p in zip(pts, pts[1:]) if p[0] > prev[0]]
    return as_control(dedup)


def _with_release(vb, hold: float, release: float):
    """vb over [0, hold], then a linear fall to 0 over `release` seconds."""
    held = _clip(vb, hold)
    at_hold = float(held.at(hold)) if isinstance(held, Curve) else float(held)
    pts = held.to_list() if isinstance(held, Curve) else [[0.0, at_hold], [hold, at_hold]]
    if pts[-1][0] < hold:
        pts.append([hold, at_hold])
    if pts[0][0] == hold == 0.0:
        pts = [[0.0, at_hold]]
    pts.append([hold + release, 0.0])
    return as_control(pts)


def _scale(control, k: float):
    if isinstance(control, Curve):
        return Curve(tuple((t, v * k) for t, v in control.points))
    return float(control) * k


def _num(where: str, key: str, v, lo=None, hi=None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ScoreError(f"{where}: {key} must be a number, got {v!r}")
    if lo is not None and v < lo:
        raise ScoreError(f"{where}: {key} must be >= {lo:g}, got {v:g}")
    if hi is not None and v > hi:
        raise ScoreError(f"{where}: {key} must be <= {hi:g}, got {v:g}")
    return float(v)


def _control(where: str, key: str, v):
    if isinstance(v, Curve):
        return v
    if isinstance(v, list):
        try:
            return as_control(v)
        except SceneError as e:
            raise ScoreError(f"{where}: {key} curve: {e}") from None
    return _num(where, key, v)


def _layer(where: str, table: dict, allowed: set[str]) -> dict:
    """A table's fields with its preset expanded below them; checks keys and exclusive pairs."""
    unknown = set(table) - allowed
    if unknown:
        raise ScoreError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(allowed))})")
    for a, b in EXCLUSIVE:
        if a in table and b in table:
            raise ScoreError(f"{where}: both {a} and {b} given; a note takes one of them")
    fields = {}
    if "preset" in table:
        try:
            fields.update(load_preset(str(table["preset"])))
        except UsageError as e:
            raise ScoreError(f"{where}: {e}") from None
    for a, b in EXCLUSIVE:  # an explicit key replaces its partner from the preset
        if a in table:
            fields.pop(b, None)
        if b in table:
            fields.pop(a, None)
    fields.update({k: v for k, v in table.items() if k not in ("preset", "note", "name")})
    return fields


def _merge(*layers: dict) -> dict:
    out: dict = {}
    for layer in layers:
        for a, b in EXCLUSIVE:
            if a in layer:
                out.pop(b, None)
            if b in layer:
                out.pop(a, None)
        out.update(layer)
    return out


def note_from_fields(name: str, fields: dict, where: str, a4: float = 440.0, label: str = "") -> Note:
    """A Note from merged score fields (start, duration, pitch or f0, fb or beta, vb, a, release, ...)."""
    from . import pitch as P

    d = Scene()
    start = _num(where, "start", fields.get("start", 0.0), lo=0.0)
    hold = _num(where, "duration", fields.get("duration", d.duration), lo=0.0)
    if hold <= 0:
        raise ScoreError(f"{where}: duration must be > 0 s, got {hold:g}")
    release = _num(where, "release", fields.get("release", RELEASE), lo=0.0, hi=MAX_RELEASE)
    a = _num(where, "a", fields.get("a", d.a))
    vb = _control(where, "vb", fields.get("vb", d.vb))
    rate = fields.get("sample_rate", d.sample_rate)
    beta = _control(where, "beta", fields["beta"]) if "beta" in fields else None
    fb = None if beta is not None else _control(where, "fb", fields.get("fb", d.fb))
    rest = {k: fields[k] for k in ("q0", "p0") if k in fields}
    try:
        curve = _pitch_points(where, fields, a4)  # a moving pitch: [(t, Hz), ...], else None
        if curve is not None:  # each breakpoint tuned with the note's held bow (docs/score.md, "Pitch curves")
            held = dict(vb=P.held_value(vb, hold), a=a, a4=a4)
            f0s = [P.tune(h, None, beta=P.held_value(beta, hold), **held).f0 if beta is not None
                   else P.tune(h, P.held_value(fb, hold), **held).f0 for _, h in curve]
            hz = curve[0][1]
            f0 = as_control([(t, f) for (t, _), f in zip(curve, f0s)])
        elif "pitch" in fields:
            hz = P.parse_pitch(fields["pitch"], a4)
            held = dict(vb=P.held_value(vb, hold), a=a)
            if beta is not None:
                f0 = P.tune(hz, None, beta=P.held_value(beta, hold), a4=a4, **held).f0
            else:
                f0 = P.tune(hz, P.held_value(fb, hold), a4=a4, **held).f0
        else:
            hz = None
            f0 = _num(where, "f0", fields.get("f0", d.f0))
        if beta is not None and isinstance(f0, Curve):  # F_B / w held: the force follows the pitch
            if isinstance(as_control(beta), Curve):
                raise ScoreError(f"{where}: a pitch curve plays with a constant beta (or fb)")
            fb = Curve(tuple((t, float(beta) * physics.omega(f)) for t, f in f0.points))
        elif beta is not None:
            fb = _scale(beta, physics.omega(f0))
        if release > 0:
            fb_end = float(Scene(f0=f0, fb=fb, a=a).fb_at(hold + release))
            f0_end = float(Scene(f0=f0, fb=fb, a=a).f0_at(hold + release))
            vb_full, duration = _with_release(vb, hold, release), hold + release + stop_tail(fb_end, f0_end, a)
        else:
            vb_full, duration = vb, hold
        scene = Scene(f0=f0, fb=fb, vb=vb_full, a=a, duration=duration, sample_rate=rate, **rest)
    except UsageError as e:
        raise ScoreError(f"{where}: {e}") from None
    return Note(name, scene, start=start, hold=hold, release=release, pitch=hz,
                label=label or where)


MAX_PITCH_POINTS = 4096  # a pitch curve's breakpoints (the operator's curve path holds as many)
CENTS_STEP = 0.005  # s: a cents curve is sampled this often between its breakpoints (linear in Hz, not in cents)


def _pitch_points(where: str, fields: dict, a4: float):
    """A note's moving pitch as [(t, Hz), ...]: `pitch` as breakpoints [[t, "A4"], [t, 440.0], ...] and/or `cents`
    as breakpoints [[t, cents], ...] added to it; None for a pitch that holds."""
    from . import pitch as P

    pitch, cents = fields.get("pitch"), fields.get("cents")
    if not isinstance(pitch, list) and cents is None:
        return None
    if isinstance(pitch, list):
        try:
            base = as_control([(float(t), P.parse_pitch(v, a4)) for t, v in pitch])
        except (TypeError, ValueError):
            raise ScoreError(f"{where}: a pitch curve is [[seconds, pitch], ...] (pitch a note name or Hz), got "
                             f"{pitch!r}") from None
        except SceneError as e:
            raise ScoreError(f"{where}: pitch curve: {e}") from None
    elif "pitch" in fields:
        base = P.parse_pitch(pitch, a4)
    else:
        raise ScoreError(f"{where}: cents moves a pitch: give pitch too")
    c = _control(where, "cents", cents) if cents is not None else 0.0
    times = set(controls_times(base)) | set(controls_times(c))
    if isinstance(c, Curve):  # 2^(c / 1200) is not linear in c: sample between the cents breakpoints
        times |= set(np.arange(0.0, c.times[-1], CENTS_STEP).tolist())
    t = np.array(sorted(times))
    hz = (base.at(t) if isinstance(base, Curve) else np.full(len(t), float(base)))
    hz = hz * 2.0 ** ((c.at(t) if isinstance(c, Curve) else float(c)) / 1200.0)
    if len(t) > MAX_PITCH_POINTS:
        raise ScoreError(f"{where}: the pitch curve needs {len(t)} breakpoints, at most {MAX_PITCH_POINTS}")
    return list(zip(t.tolist(), hz.tolist()))


def controls_times(c) -> list[float]:
    return c.times.tolist() if isinstance(c, Curve) else [0.0]


def load_toml_score(path) -> list[Note]:
    p = Path(path)
    if not p.is_file():
        raise ScoreError(f"score file {p} not found")
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ScoreError(f"score {p} is not valid TOML ({e})") from None
    except RecursionError:  # tomllib recurses per level of nesting; no score nests more than a few levels
        raise ScoreError(f"score {p} nests arrays or tables too deeply to be a score") from None
    unknown = set(data) - set(TOP_KEYS)
    if unknown:
        raise ScoreError(f"score {p}: unknown top-level key(s) {', '.join(sorted(unknown))} (known: "
                         f"{', '.join(f'{k} ({v})' for k, v in TOP_KEYS.items())})")
    from .pitch import A4_HZ, check_a4

    try:
        a4 = check_a4(data.get("a4", A4_HZ))
    except UsageError as e:
        raise ScoreError(f"score {p}: {e}") from None
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ScoreError(f"score {p}: [defaults] must be a table")
    base = _layer(f"score {p}, [defaults]", defaults, DEFAULT_KEYS)
    voices = data.get("voice")
    if not isinstance(voices, list) or not voices:
        raise ScoreError(f"score {p} has no [[voice]] entries")
    notes, names = [], set()
    for i, v in enumerate(voices):
        if not isinstance(v, dict):
            raise ScoreError(f"score {p}: voice {i + 1} is not a table")
        name = str(v.get("name", f"voice{i + 1}"))
        if name in names:
            raise ScoreError(f"score {p}: voice {name!r} is defined twice (give each [[voice]] its own name)")
        names.add(name)
        where = f"score {p}, voice {name!r}"
        layer = _layer(where, v, VOICE_KEYS)
        note_tables = v.get("note")
        if note_tables is None:  # the round-1 form: the voice is one note from its start (default 0)
            notes.append(note_from_fields(name, _merge(base, layer), where, a4, label=name))
            continue
        if not isinstance(note_tables, list) or not note_tables:
            raise ScoreError(f"{where}: note must be an array of tables ([[voice.note]])")
        if "start" in v:
            raise ScoreError(f"{where}: start belongs to each [[voice.note]], not to a voice with notes")
        for j, nt in enumerate(note_tables):
            w = f"{where}, note {j + 1}"
            if not isinstance(nt, dict):
                raise ScoreError(f"{w} is not a table")
            notes.append(note_from_fields(name, _merge(base, layer, _layer(w, nt, NOTE_KEYS)), w, a4,
                                          label=f"{name} #{j + 1}"))
    return notes


class ScoreNotes(list):
    """A score's notes, and what the reader changed or dropped on the way (`remarks`, one line each, for the user:
    `score` prints them before it renders)."""

    def __init__(self, notes=(), remarks=()):
        super().__init__(notes)
        self.remarks = list(remarks)


def load_midi_score(path, a4: float = 440.0, bend_range: float | None = None) -> ScoreNotes:
    """The notes of a MIDI file with the bow of `bowsynth.midi`'s mapping; a track's channel is a voice."""
    from . import midi as M

    piece = read_midi_checked(path)
    notes = ScoreNotes(remarks=piece.remarks)
    bend_range = M.BEND_RANGE if bend_range is None else bend_range
    for n in piece.notes:
        hold = n.end - n.start
        beta = _midi_control(piece, n, M.CC_PRESSURE, M.bow_beta)
        vb = _midi_control(piece, n, M.CC_EXPRESSION, M.bow_vb)
        voice = n.voice
        from .pitch import note_name, midi_to_hz

        where = f"{Path(path).name}: {voice} note {note_name(midi_to_hz(n.number, a4), a4)} at {n.start:.3f} s"
        if not 12 <= n.number <= 119:
            raise ScoreError(f"{where}: MIDI note {n.number} is outside C0..B8")
        fields = {"start": n.start, "duration": hold, "pitch": midi_to_hz(n.number, a4), "beta": beta, "vb": vb}
        semis = M.pitch_curve(piece, n.channel, n.start, n.start + hold + RELEASE, bend_range)
        if semis is not None:  # the pitch wheel and CC1 (vibrato), as `play` reads them
            fields["cents"] = [[t, 100.0 * v] for t, v in semis]
        notes.append(note_from_fields(voice, fields, where, a4, label=where.split(": ", 1)[1]))
        notes[-1].extra = {"midi_note": n.number, "velocity": n.velocity}
    return notes


def read_midi_checked(path):
    from .midi import read_midi

    return read_midi(path)


def _midi_control(piece, n, cc, bow):
    """The note's bow control (bow: midi.bow_beta or midi.bow_vb, the mapping `play` shares) over its controller."""
    from .midi import controller_curve

    pts = controller_curve(piece, n.channel, cc, n.start, n.end)
    return as_control([(t, bow(n.velocity, v)) for t, v in pts])


def load_score(path, a4: float | None = None, bend_range: float | None = None) -> list[Note]:
    """The notes of a TOML score or a MIDI file (told apart by content and name)."""
    from .midi import is_midi
    from .pitch import A4_HZ, check_a4

    if is_midi(path):
        return load_midi_score(path, check_a4(A4_HZ if a4 is None else a4), bend_range)
    if bend_range is not None:
        raise ScoreError("--bend-range applies to MIDI files' pitch wheel; a TOML score writes its pitch curves")
    if a4 is not None:
        raise ScoreError("--a4 retunes MIDI files; a TOML score sets its own with a top-level a4 = ...")
    return load_toml_score(path)


def voices_from_presets(names: list[str], **overrides) -> list[Note]:
    from .scene import make_scene

    seen: dict[str, int] = {}
    out = []
    for n in names:  # a preset listed twice is two voices: name, name-2, ...
        seen[n] = seen.get(n, 0) + 1
        name = n if seen[n] == 1 else f"{n}-{seen[n]}"
        out.append(Note(name, make_scene(n, **overrides), label=name))
    return out


# --- what the models cover ----------------------------------------------------------------------------------------

def score_box(notes: list[Note]) -> dict:
    """The box of dimensionless physics the notes visit during their sustains (the release is the FDM's):
    {'beta': (lo, hi), 'vb': (lo, hi), 'a': (lo, hi), 'f0': (lo, hi), 'notes': n, 'gestures': n with curves}."""
    if not notes:
        raise ScoreError("no notes")
    sus = [n.sustain_scene() for n in notes]
    bl = [s.beta_range for s in sus]
    vl = [s.vb_range for s in sus]
    return {"beta": (min(b[0] for b in bl), max(b[1] for b in bl)), "vb": (min(v[0] for v in vl), max(v[1] for v in vl)),
            "a": (min(s.a for s in sus), max(s.a for s in sus)), "f0": (min(s.f0 for s in sus), max(s.f0 for s in sus)),
            "notes": len(notes), "gestures": sum(s.varying for s in sus)}


def uncovered(notes: list[Note], model=None) -> list[tuple[Note, str]]:
    """The notes no operator model can play (their sustain), each with the reason."""
    from .rollout import _resolve, available_models

    models = None
    if model is None:
        models = available_models()
    else:
        from .rollout import as_model

        model = as_model(model)
    out = []
    for n in notes:
        sc = n.rollout_scene()
        try:
            _resolve(sc, model, models)
        except DomainError:
            (blo, bhi), (vlo, vhi) = sc.beta_range, sc.vb_range
            b = f"{blo:.4g}" if blo == bhi else f"{blo:.4g}..{bhi:.4g}"
            v = f"{vlo:g}" if vlo == vhi else f"{vlo:g}..{vhi:g}"
            out.append((n, f"F_B / w = {b}, v_B = {v}, a = {sc.a:g}"))
    return out


def coverage_message(notes: list[Note], missing: list[tuple[Note, str]], source=None) -> str:
    box = score_box(notes)
    shown = "; ".join(f"{n.describe()} ({why})" for n, why in missing[:3])
    more = f"; and {len(missing) - 3} more" if len(missing) > 3 else ""
    train = f"bowsynth train --score {source}" if source else "bowsynth train"
    return (f"{len(missing)} of {len(notes)} notes fall outside every model's range: {shown}{more}. The piece spans "
            f"F_B / w {box['beta'][0]:.4g}..{box['beta'][1]:.4g}, v_B {box['vb'][0]:g}..{box['vb'][1]:g}, "
            f"a {box['a'][0]:g}..{box['a'][1]:g}: train a model that covers it with `{train}`, or render with "
            f"--method fdm (or --fallback fdm for these notes only)")


# --- rendering ----------------------------------------------------------------------------------------------------

def render_notes(notes: list[Note], method: str = "operator", model=None, fallback: str = "none",
                 source=None) -> list[Render]:
    """Render every note: with the FDM whole (it follows the curves), or with the operator in one batched rollout
    of the sustains, each release then by the FDM from the sustain's last state. Notes no model covers are
    refused before anything renders (fallback 'fdm': rendered by the FDM instead, noted in info['notes'])."""
    from .engines import Engine, Fallback, parse_choice, render

    engine = parse_choice(Engine, method, "--method")
    fb_mode = parse_choice(Fallback, fallback, "--fallback")
    if engine is Engine.fdm:
        return render([n.scene for n in notes], engine="fdm")
    missing = {id(n): why for n, why in uncovered(notes, model)}
    if missing and fb_mode is not Fallback.fdm:
        raise ScoreError(coverage_message(notes, [(n, missing[id(n)]) for n in notes if id(n) in missing], source))
    out: list = [None] * len(notes)
    op = [i for i, n in enumerate(notes) if id(n) not in missing]
    for i, n in enumerate(notes):
        if id(n) in missing:
            r = render(n.scene, engine="fdm")
            r.info.setdefault("notes", []).append(f"no model covers it ({missing[id(n)]}): rendered by the FDM")
            out[i] = r
    # a note whose bow stop and tail a model covers too (a box reaching v_B = 0) is played whole by the operator
    whole = [i for i in op if notes[i].release > 0 and _plays_whole(notes[i], model)]
    if whole:
        for i, r in zip(whole, render([notes[i].scene for i in whole], engine="operator", model=model,
                                      fallback=fallback)):
            r.info["release"] = "operator"
            out[i] = r
    part = [i for i in op if i not in set(whole)]
    if part:
        sustains = [notes[i].rollout_scene() for i in part]
        rs = render(sustains, engine="operator", model=model, fallback=fallback)
        for i, r in zip(part, finish_releases([notes[i] for i in part], rs)):
            out[i] = r
    return out


def _plays_whole(note: Note, model=None) -> bool:
    """Does the model that would play the note (the one given, else the lookup's pick) cover the whole note, its bow
    stop and tail included?"""
    from .rollout import as_model, find_model

    try:
        m = find_model(note.scene) if model is None else as_model(model)
    except DomainError:
        return False
    return m.covers(note.scene)


def _release_scene(note: Note, sus: Render) -> Scene:
    """The note after its sustain: v_B falls to 0 over the release, from the sustain's state at the hold."""
    sc, h = note.scene, note.hold_samples
    if sc.pitch_varies:  # the pitch (and a force that follows it) go on along their curves from the hold's sample
        from .controls import after

        t0 = h / sc.sample_rate
        f0, fb = after(sc.f0, t0), after(sc.fb, t0)
    else:
        f0, fb = sc.f0, float(sc.fb_at(note.hold))
    return Scene(f0=f0, fb=fb, vb=[[0.0, float(sc.vb_at(note.hold))], [note.release, 0.0]],
                 a=sc.a, duration=(sc.n_samples - h) / sc.sample_rate, sample_rate=sc.sample_rate,
                 q0=float(sus.q[h]), p0=float(sus.p[h]))


def finish_releases(notes: list[Note], sustains: list[Render], loop: str = "auto") -> list[Render]:
    """Each note's release by the FDM from its sustain's state at the hold, written over the sustain's samples from
    there on (`sustains` rendered from `Note.rollout_scene`, so they already span the whole note).

    The releases run together in one numpy FDM (`fdm.fdm_batch`, one batch per sample rate and oversampling): a few
    thousand steps of a few small array operations, where the compiled loop would first cost numba's import and load
    (~1 s, more than a 100-note score's whole rollout). Same scheme, start and Newton iteration as `render_fdm`.
    Where numba is already loaded (a long piece's compiled rollout paid for it), each release runs `render_fdm`'s
    compiled loop instead: the 8 releases of 0.1 s of a 60 s piece took 0.37 s in numpy and 4-5 ms compiled.
    loop: 'auto' (that choice, rollout.numba_loaded), 'numpy' or 'numba'."""
    from .fdm import check_oversample, fdm_batch, render_fdm
    from .rollout import numba_loaded

    if loop == "auto":
        loop = "numba" if numba_loaded() else "numpy"
    if loop not in ("numpy", "numba"):
        raise ValueError(f"loop must be auto, numpy or numba, got {loop!r}")

    out = [None] * len(notes)
    groups: dict[tuple, list[int]] = {}
    scenes = {}
    for i, (n, sus) in enumerate(zip(notes, sustains)):
        if n.release <= 0:
            out[i] = Render(n.scene, sus.t, sus.q, sus.p, sus.method, sus.seconds, sus.info)
            continue
        if len(sus.q) != n.scene.n_samples:
            raise ValueError(f"{n.describe()}: the sustain has {len(sus.q)} samples, the note "
                             f"{n.scene.n_samples} (render Note.rollout_scene)")
        scenes[i] = rel = _release_scene(n, sus)
        os_ = check_oversample(rel, 1, warn=False)
        # a moving pitch: the compiled FDM, which follows w(t) (the numpy batch holds one w per note)
        groups.setdefault((rel.sample_rate, os_, rel.a, rel.pitch_varies), []).append(i)
    for (sr, os_, a, moving), idx in groups.items():
        rel = [scenes[i] for i in idx]
        if loop == "numba" or moving:
            for i, r in zip(idx, rel):
                f = render_fdm(r, os_)
                out[i] = _join_release(notes[i], sustains[i], f.q, f.p, f.seconds)
            continue
        vb0 = np.array([r.vb_at(0.0) for r in rel])
        span = np.array([notes[i].release for i in idx])
        k = 1.0 / (sr * os_)
        n_out = max(r.n_samples for r in rel)
        t0 = time.perf_counter()
        # the ramp as controls.Curve evaluates it (v0 + (v1 - v0) (t - t0) / (t1 - t0)), held at 0 after it
        q, p = fdm_batch([r.q0 for r in rel], [r.p0 for r in rel], n_out, os_, k, np.array([r.omega for r in rel]),
                         np.array([float(r.fb_at(0.0)) for r in rel]),
                         lambda t: np.where(t >= span, 0.0, vb0 + (0.0 - vb0) * t / span), a)
        secs = (time.perf_counter() - t0) / len(idx)
        for row, i in enumerate(idx):
            m = scenes[i].n_samples
            out[i] = _join_release(notes[i], sustains[i], q[row, :m], p[row, :m], secs)
    return out


def _join_release(n: Note, sus: Render, q: np.ndarray, p: np.ndarray, secs: float) -> Render:
    """The note: its sustain up to the hold, the release's samples written over the rest."""
    h = n.hold_samples
    sus.q[h:] = q
    sus.p[h:] = p
    info = dict(sus.info)
    info["release"] = "fdm"
    return Render(n.scene, sus.t, sus.q, sus.p, method=f"{sus.method} + fdm release", seconds=sus.seconds + secs,
                  info=info)


def render_voices(voices, method: str = "operator", model=None, fallback: str = "none") -> list[Render]:
    return render_notes(voices, method=method, model=model, fallback=fallback)


# --- writing ------------------------------------------------------------------------------------------------------

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
_WORST_METHOD = "operator+fdm + fdm release"
_WORST_FLOAT = 1 / 3
_WORST_MODEL = "x" * 64


def check_stems_fit(notes: list[Note], signal: str = "u", dc: str = "remove") -> None:
    """Before rendering: every note's stem metadata (wav.render_meta, scene and curves included) fits a WAV comment
    (else a one-line ScoreError naming the note)."""
    from .wav import META_LIMIT, render_meta

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
    from .wav import check_meta_fits

    if stems is not None:
        check_stems_fit(notes, signal, dc)
    if mix is not None:
        from .wav import mix_meta

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

    from .outfile import signals_held
    from .wav import DC_TAG, write_wav

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
        with signals_held():
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
        sig = np.asarray(r.q if signal == "u" else r.signal(signal), float)
        x[s:s + len(sig)] += sig
    return x, rate


def write_voices(voices, renders, out: Path, mix: bool, signal: str = "u", stems: Path | None = None,
                 dc: str = "remove", gain_db: float | None = None, force: bool = True) -> list[Path]:
    """Stems (one file per note) into the directory `out`, or (mix=True) the mix into the file `out` (and, with
    `stems`, the stems into that directory; the mix's metadata points to them for `compare`).

    DC (dc='remove'): each stem is filtered on its own, and the mix is the sum of the unfiltered notes at their
    starts, filtered once. The filter (wav.remove_dc) is zero-phase with a mean subtraction, so it does not commute
    with placing notes at other starts: the mix equals remove_dc(sum of the notes as rendered), not the sum of the
    filtered stems (tests/test_midi.py checks the first exactly)."""
    from .wav import write_mix

    if not mix:
        return write_stems(voices, renders, out, signal, dc=dc, gain_db=gain_db, force=force)
    paths = []
    if stems is not None:
        paths += write_stems(voices, renders, stems, signal, dc=dc, gain_db=gain_db, force=force)
    x, rate = mix_notes(voices, renders, signal)
    write_mix(out, x, _voice_names(voices), rate, dc=dc, gain_db=gain_db, force=force,
              **_mix_extra(voices, out, stems, signal))
    return [out] + paths
