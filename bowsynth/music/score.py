"""Scores: notes in time (`Note`s), read from a TOML score (docs/score.md), a MIDI file (`bowsynth.music.midi`) or a
list of presets, for `bowsynth score` to render in one batched rollout and mix with each note at its start.
`load_score` reads either kind of file.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

from .. import physics
from ..controls import Curve, as_control
from ..errors import SceneError, UsageError
from ..io.infile import regular_file
from ..scene import Scene, load_preset
from .note import MAX_RELEASE, RELEASE, Note, scaled, with_release, stop_tail
from .pitch_curve import pitch_points

TOP_KEYS = {"defaults": "table of note defaults", "voice": "array of voice tables", "a4": "tuning, Hz",
            "title": "text"}
NOTE_KEYS = {"start", "duration", "pitch", "f0", "fb", "beta", "vb", "a", "release", "preset", "sample_rate",
             "q0", "p0", "cents"}
VOICE_KEYS = NOTE_KEYS | {"name", "note"}
DEFAULT_KEYS = NOTE_KEYS - {"start"}
EXCLUSIVE = (("pitch", "f0"), ("fb", "beta"))


class ScoreError(UsageError):
    """A score (TOML or MIDI) that cannot be played as written (a UsageError: CLI exit code 2).

    Examples
    --------
    >>> load_score("no-such-score.toml")
    Traceback (most recent call last):
    ...
    bowsynth.music.score.ScoreError: score file no-such-score.toml not found
    """


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


def note_from_fields(name: str, fields: dict, where: str, a4: float = 440.0, label: str = "", ratio_for=None) -> Note:
    """A Note from merged score fields (start, duration, pitch or f0, fb or beta, vb, a, release, ...).

    Parameters
    ----------
    name : str
        The note's voice.
    fields : dict
        The note's fields, its defaults and voice merged (a score's keys: docs/score.md).
    where, label : str
        Where the note is, and what it is called (default `where`), for messages.
    a4 : float
        Hz, the tuning of note names.
    ratio_for : callable, optional
        ratio_for(scene): the sounding ratio of the engine that will play it (`engine_tuning.ratio_for_engine`),
        which a pitch is tuned with; else the truth's.

    Returns
    -------
    Note

    Raises
    ------
    ScoreError
        A field outside its range.

    Examples
    --------
    >>> n = note_from_fields("solo", {"pitch": "A3", "duration": 0.2, "beta": 0.15915494}, "solo")
    >>> n.pitch, n.hold, n.release
    (220.0, 0.2, 0.05)
    """
    from . import tuning as P
    from .notes import parse_pitch

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
        curve = pitch_points(where, fields, a4)  # a moving pitch: [(t, Hz), ...], else None
        if curve is not None:  # each breakpoint tuned with the note's held bow (docs/score.md, "Pitch curves")
            held = dict(vb=P.held_value(vb, hold), a=a, a4=a4)

            def tuned(h):
                ratio = None
                if ratio_for is not None:
                    probe_fb = scaled(beta, physics.omega(h)) if beta is not None else fb
                    # a moving pitch rolls in free windows: the probe's pitch is a curve too (held at h)
                    ratio = ratio_for(Scene(f0=Curve(((0.0, h), (hold, h))), fb=probe_fb, vb=vb, a=a, duration=hold,
                                            sample_rate=rate))
                if beta is not None:
                    return P.tune(h, None, beta=P.held_value(beta, hold), ratio=ratio, **held).f0
                return P.tune(h, P.held_value(fb, hold), ratio=ratio, **held).f0
            hz = curve[0][1]
            f0 = as_control([(t, tuned(h)) for t, h in curve])
        elif "pitch" in fields:
            hz = parse_pitch(fields["pitch"], a4)
            held = dict(vb=P.held_value(vb, hold), a=a)
            ratio = None
            if ratio_for is not None:
                probe_fb = scaled(beta, physics.omega(hz)) if beta is not None else fb
                ratio = ratio_for(Scene(f0=hz, fb=probe_fb, vb=vb, a=a, duration=hold, sample_rate=rate))
            if beta is not None:
                f0 = P.tune(hz, None, beta=P.held_value(beta, hold), a4=a4, ratio=ratio, **held).f0
            else:
                f0 = P.tune(hz, P.held_value(fb, hold), a4=a4, ratio=ratio, **held).f0
        else:
            hz = None
            f0 = _num(where, "f0", fields.get("f0", d.f0))
        if beta is not None and isinstance(f0, Curve):  # F_B / w held: the force follows the pitch
            if isinstance(as_control(beta), Curve):
                raise ScoreError(f"{where}: a pitch curve plays with a constant beta (or fb)")
            fb = Curve(tuple((t, float(beta) * physics.omega(f)) for t, f in f0.points))
        elif beta is not None:
            fb = scaled(beta, physics.omega(f0))
        if release > 0:
            fb_end = float(Scene(f0=f0, fb=fb, a=a).fb_at(hold + release))
            f0_end = float(Scene(f0=f0, fb=fb, a=a).f0_at(hold + release))
            vb_full, duration = with_release(vb, hold, release), hold + release + stop_tail(fb_end, f0_end, a)
        else:
            vb_full, duration = vb, hold
        scene = Scene(f0=f0, fb=fb, vb=vb_full, a=a, duration=duration, sample_rate=rate, **rest)
    except UsageError as e:
        raise ScoreError(f"{where}: {e}") from None
    return Note(name, scene, start=start, hold=hold, release=release, pitch=hz,
                label=label or where)


def load_toml_score(path, ratio_for=None) -> list[Note]:
    """The notes of a TOML score, in the order written; see `load_score` (which reads this and MIDI files) for the
    format, and `note_from_fields` for `ratio_for`."""
    p = Path(path)
    regular_file(p, "score file", "a score file", ScoreError)
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
    from .notes import A4_HZ, check_a4

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
            notes.append(note_from_fields(name, _merge(base, layer), where, a4, label=name, ratio_for=ratio_for))
            continue
        if not isinstance(note_tables, list) or not note_tables:
            raise ScoreError(f"{where}: note must be an array of tables ([[voice.note]])")
        if "start" in v:
            raise ScoreError(f"{where}: start belongs to each [[voice.note]], not to a voice with notes")
        for j, nt in enumerate(note_tables):
            w = f"{where}, note {j + 1}"
            if not isinstance(nt, dict):
                raise ScoreError(f"{w} is not a table")
            notes.append(note_from_fields(name, _merge(base, layer, _layer(w, nt, NOTE_KEYS)), w, a4, ratio_for=ratio_for,
                                          label=f"{name} #{j + 1}"))
    return notes


class ScoreNotes(list):
    """A score's notes (a list of `Note`), and what the reader changed or dropped on the way (`remarks`, one line
    each, for the user: `score` prints them before it renders).

    Examples
    --------
    >>> ScoreNotes([], ["a note-off with no note-on was dropped"]).remarks
    ['a note-off with no note-on was dropped']
    """

    def __init__(self, notes=(), remarks=()):
        super().__init__(notes)
        self.remarks = list(remarks)


def load_midi_score(path, a4: float = 440.0, ratio_for=None, bend_range: float | None = None) -> ScoreNotes:
    """The notes of a MIDI file with the bow of `bowsynth.music.midi`'s mapping; a track's channel is a voice.

    Parameters
    ----------
    path : str or Path
        A standard MIDI file.
    a4, ratio_for
        As `note_from_fields` takes them.
    bend_range : float, optional
        Semitones of the pitch wheel (default `bowsynth.music.midi.BEND_RANGE`).

    Returns
    -------
    ScoreNotes
        Each note with `extra` {'midi_note', 'velocity'}, and the reader's `remarks`.

    Raises
    ------
    ScoreError
        A note outside C0..B8, or a file that is not MIDI.

    Examples
    --------
    >>> import mido
    >>> a4 = [mido.Message("note_on", note=69, velocity=64), mido.Message("note_off", note=69, time=240)]
    >>> mido.MidiFile(tracks=[a4]).save("a4.mid")
    >>> notes = load_midi_score("a4.mid")
    >>> [(n.name, n.pitch, n.hold, n.extra["velocity"]) for n in notes], notes.remarks
    ([('ch1', 440.0, 0.25, 64)], [])
    """
    from . import midi as M
    from .midi import read_midi

    piece = read_midi(path)
    notes = ScoreNotes(remarks=piece.remarks)
    bend_range = M.BEND_RANGE if bend_range is None else bend_range
    for n in piece.notes:
        hold = n.end - n.start
        beta = _midi_control(piece, n, M.CC_PRESSURE, M.bow_beta)
        vb = _midi_control(piece, n, M.CC_EXPRESSION, M.bow_vb)
        voice = n.voice
        from .notes import midi_to_hz, note_name

        where = f"{Path(path).name}: {voice} note {note_name(midi_to_hz(n.number, a4), a4)} at {n.start:.3f} s"
        if not 12 <= n.number <= 119:
            raise ScoreError(f"{where}: MIDI note {n.number} is outside C0..B8")
        fields = {"start": n.start, "duration": hold, "pitch": midi_to_hz(n.number, a4), "beta": beta, "vb": vb}
        semis = M.pitch_curve(piece, n.channel, n.start, n.start + hold + RELEASE, bend_range)
        if semis is not None:  # the pitch wheel and CC1 (vibrato), as `play` reads them
            fields["cents"] = [[t, 100.0 * v] for t, v in semis]
        notes.append(note_from_fields(voice, fields, where, a4, label=where.split(": ", 1)[1], ratio_for=ratio_for))
        notes[-1].extra = {"midi_note": n.number, "velocity": n.velocity}
    return notes


def _midi_control(piece, n, cc, bow):
    """The note's bow control (bow: midi.bow_beta or midi.bow_vb, the mapping `play` shares) over its controller."""
    from .midi import controller_curve

    pts = controller_curve(piece, n.channel, cc, n.start, n.end)
    return as_control([(t, bow(n.velocity, v)) for t, v in pts])


def load_score(path, a4: float | None = None, ratio_for=None, bend_range: float | None = None) -> list[Note]:
    """The notes of a TOML score or a MIDI file (told apart by content and name), each pitch tuned for the engine
    ratio_for(scene) names (see note_from_fields). What a note is: `bowsynth.music.note.Note`.

    Parameters
    ----------
    path : str or Path
        A TOML score (docs/score.md has the whole format) or a MIDI file (`load_midi_score`).
    a4 : float, optional
        Hz: retunes a MIDI file (default 440); a TOML score sets its own with a top-level a4 = ...
    ratio_for : callable, optional
        As `note_from_fields` takes it.
    bend_range : float, optional
        A MIDI file's pitch wheel range, semitones; a TOML score writes its pitch curves.

    Returns
    -------
    list of Note
        In the order written (a MIDI file's: a `ScoreNotes`, with its remarks).

    Raises
    ------
    ScoreError
        A file that cannot be read or played as written (`load_score("no-such-score.toml")`), or a4 / bend_range
        given for a TOML score.

    Examples
    --------
    >>> from pathlib import Path
    >>> _ = Path("score.toml").write_text('''a4 = 440.0
    ... [defaults]
    ... beta = 0.15915494     # F_B / w, so one model plays every pitch (or fb = 100.0, a fixed force)
    ... vb = 0.2
    ... release = 0.05        # the bow slows to a stop over 50 ms after each note's duration
    ... [[voice]]
    ... name = "melody"
    ... [[voice.note]]
    ... start = 0.0
    ... duration = 0.5
    ... pitch = "A4"
    ... [[voice.note]]
    ... start = 0.5
    ... duration = 1.0
    ... pitch = "C#5"
    ... vb = [[0.0, 0.15], [0.8, 0.25]]   # a gesture: times from the note's start
    ... ''')
    >>> [(n.label, n.start, n.hold, round(n.pitch, 2), n.gesture) for n in load_score("score.toml")]
    [('melody #1', 0.0, 0.5, 440.0, False), ('melody #2', 0.5, 1.0, 554.37, True)]
    """
    from .midi import is_midi
    from .notes import A4_HZ, check_a4

    if is_midi(path):
        return load_midi_score(path, check_a4(A4_HZ if a4 is None else a4), ratio_for=ratio_for, bend_range=bend_range)
    if bend_range is not None:
        raise ScoreError("--bend-range applies to MIDI files' pitch wheel; a TOML score writes its pitch curves")
    if a4 is not None:
        raise ScoreError("--a4 retunes MIDI files; a TOML score sets its own with a top-level a4 = ...")
    return load_toml_score(path, ratio_for=ratio_for)


def voices_from_presets(names: list[str], **overrides) -> list[Note]:
    """One note per preset, each its own voice from 0 s (a preset listed twice is two voices: name, name-2, ...).

    Parameters
    ----------
    names : list of str
        Preset names (`bowsynth.scene.list_presets`).
    **overrides
        `bowsynth.music.request.make_scene`'s keywords for every note (pitch=, duration=, ...).

    Returns
    -------
    list of Note

    Examples
    --------
    >>> [(n.name, n.scene.duration) for n in voices_from_presets(["paper-fb100", "paper-fb100"], duration=0.2)]
    [('paper-fb100', 0.2), ('paper-fb100-2', 0.2)]
    """
    from ..music.request import make_scene

    seen: dict[str, int] = {}
    out = []
    for n in names:  # a preset listed twice is two voices: name, name-2, ...
        seen[n] = seen.get(n, 0) + 1
        name = n if seen[n] == 1 else f"{n}-{seen[n]}"
        out.append(Note(name, make_scene(n, **overrides), label=name))
    return out


# --- what the models cover ----------------------------------------------------------------------------------------


# --- rendering ----------------------------------------------------------------------------------------------------


# --- writing ------------------------------------------------------------------------------------------------------


