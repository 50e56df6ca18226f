"""Standard MIDI files (read with mido) as notes with a bow: the mapping from velocity and controllers to the bow.

Types 0 and 1 (running status is mido's business); type 2 and SMPTE-timed files are refused by name. A voice is a
track's channel: real files keep each part on its own track and often all parts on channel 1 (a chorale exported from
a public corpus does), and read as channel = voice, unisons between parts cut each other. A voice is named `chN` when
its channel is used by one track only, else `tT-chN` (T the track's index). A note-on with velocity 0 is a note-off; a
note-on of a note that already sounds in its voice ends the sounding one there (a retrigger); a note with no note-off
ends at the end of the file; a note of zero length is dropped; each of these is counted in `MidiPiece.remarks`, which
`score` prints. Controllers act on their channel, whatever the track (as a synthesizer receives them). Sustain (CC64)
and program changes are ignored.

The bow of a note (docs/score.md, "MIDI"):
- velocity v (1..127) sets the dimensionless bow force and the bow speed:
      F_B / w = 4^((v - 64) / 63) / (2 pi)     (0.040 at v 1, 0.159 at v 64, 0.637 at v 127)
      v_B     = 0.2 * 1.25^((v - 64) / 63)     (0.16 m/s at v 1, 0.2 at v 64, 0.25 at v 127)
  F_B / w rather than F_B keeps a note's timbre the same at every pitch (and v 64 is exactly the scene of the
  shipped paper-fb100 model, F_B / w = 100 / (2 pi 100), v_B 0.2, a 100). F_B = (F_B / w) 2 pi f0.
- CC2 (breath, read as bow pressure) c multiplies F_B / w by 4^((c - 64) / 63) (64 neutral, x1/4 .. x4);
- CC11 (expression) c multiplies v_B by c / 127 (127 neutral; below about 45 the bow is slower than
  1/sqrt(2a) and stops the note).
  A controller holds its last value; a change is a 5 ms ramp (a step would click); before its first message a
  controller is neutral.

The pitch of a note (docs/score.md, "Pitch curves"): the pitch wheel bends it by +-BEND_RANGE semitones at its ends
(`bend_semitones`), CC1 (modulation) adds a vibrato of depth `vibrato_depth(c)` semitones (+-50 cents at 127) at
VIBRATO_HZ, its phase starting with the note: f(t) = f 2^((bend(t) + depth(t) sin(2 pi 5.5 t)) / 12). `pitch_curve`
samples it as the note's f0 curve. `bowsynth play` reads the same messages with the same functions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import UsageError
from ..io.infile import regular_file

CC_PRESSURE, CC_EXPRESSION, CC_MODULATION = 2, 11, 1
BEND = "bend"  # the pitch wheel's key in MidiPiece.controllers (value 0..16383, 8192 centre)
BEND_RANGE = 2.0  # semitones at full bend (the General MIDI default; play --bend-range, score --bend-range)
VIBRATO_HZ = 5.5  # CC1 (modulation) is vibrato depth at this rate (a violinist's is 5-7 Hz)
VIBRATO_DEPTH = 0.5  # semitones at CC1 = 127: +-50 cents
NEUTRAL = {CC_PRESSURE: 64, CC_EXPRESSION: 127, CC_MODULATION: 0, "bend": 8192}
CC_RAMP = 0.005  # s: a controller step becomes a ramp this long
MAX_POINTS = 16  # breakpoints a controller curve keeps per note (the WAV metadata holds the scene: ~2000 characters)
BETA_AT_64 = 1.0 / (2.0 * math.pi)  # paper-fb100's F_B / w
VB_AT_64 = 0.2


@dataclass(frozen=True)
class MidiNote:
    channel: int  # 0..15
    number: int  # MIDI note number, 69 = A4
    velocity: int
    start: float  # s
    end: float  # s (the note-off)
    track: int
    voice: str = ""  # chN, or tT-chN when several tracks share the channel


@dataclass
class MidiPiece:
    path: Path
    type: int
    notes: list[MidiNote]
    controllers: dict = field(default_factory=dict)  # (channel, cc) -> [(t, value), ...] in time order
    length: float = 0.0
    remarks: list[str] = field(default_factory=list)  # what the reader changed or dropped, for the user


def velocity_beta(velocity: int) -> float:
    return BETA_AT_64 * 4.0 ** ((velocity - 64) / 63.0)


def velocity_vb(velocity: int) -> float:
    return VB_AT_64 * 1.25 ** ((velocity - 64) / 63.0)


def pressure_factor(cc: float) -> float:
    return 4.0 ** ((cc - 64) / 63.0)


def expression_factor(cc: float) -> float:
    return cc / 127.0


def bow_beta(velocity: int, pressure: float = NEUTRAL[CC_PRESSURE]) -> float:
    """F_B / w of a note struck at `velocity` with CC2 at `pressure`: the one mapping the MIDI-file reader (through
    `score`) and the live instrument (`bowsynth.live`) share. Rounded to 7 significant digits, as a score's
    breakpoints are written, so that a file and a live performance of the same events tune the same bow."""
    return float(f"{velocity_beta(velocity) * pressure_factor(pressure):.7g}")


def bow_vb(velocity: int, expression: float = NEUTRAL[CC_EXPRESSION]) -> float:
    """v_B of a note struck at `velocity` with CC11 at `expression` (see bow_beta)."""
    return float(f"{velocity_vb(velocity) * expression_factor(expression):.7g}")


def bend_semitones(value: int, bend_range: float = BEND_RANGE) -> float:
    """The pitch wheel's 14-bit value (0..16383, 8192 centre) in semitones: +-bend_range at its ends."""
    return (value - 8192) / (8191.0 if value > 8192 else 8192.0) * bend_range


def vibrato_depth(cc: float) -> float:
    """CC1 (modulation) as the vibrato's depth in semitones (0 at 0, VIBRATO_DEPTH at 127)."""
    return cc / 127.0 * VIBRATO_DEPTH


def is_midi(path) -> bool:
    """Does the file start like a standard MIDI file (or is it named like one)? Only a regular file is opened to
    look: a FIFO would block the sniff (its reader then says what it is)."""
    p = Path(path)
    if p.suffix.lower() in (".mid", ".midi", ".smf"):
        return True
    if not p.is_file():
        return False
    try:
        with p.open("rb") as fh:
            return fh.read(4) == b"MThd"
    except OSError:
        return False


def _header(p: Path) -> tuple[int, int, int] | None:
    """(format, tracks, division) of the file's MThd chunk, or None if it does not start with one."""
    with p.open("rb") as fh:
        head = fh.read(14)
    if len(head) < 14 or head[:4] != b"MThd":
        return None
    return int.from_bytes(head[8:10], "big"), int.from_bytes(head[10:12], "big"), int.from_bytes(head[12:14], "big")


def _timed_events(mid) -> list:
    """(seconds, track, message) of every track, merged in time order (ties in track order, as mido merges) through
    every tempo change, whichever track holds it."""
    merged = []
    for i, track in enumerate(mid.tracks):
        tick = 0
        for j, msg in enumerate(track):
            tick += msg.time
            merged.append((tick, i, j, msg))
    merged.sort(key=lambda e: e[:3])
    out, tempo, last_tick, t = [], 500000, 0, 0.0  # 120 bpm until a set_tempo says otherwise
    for tick, i, _, msg in merged:
        t += (tick - last_tick) * tempo / (1e6 * mid.ticks_per_beat)
        last_tick = tick
        if msg.type == "set_tempo":
            tempo = msg.tempo
        out.append((t, i, msg))
    return out


def read_midi(path) -> MidiPiece:
    """Notes (with their voices, velocities and times in seconds) and the CC2/CC11 controller changes of a MIDI
    file. Raises UsageError (one line) for a file that is not a standard MIDI file, is empty, truncated, timed in
    SMPTE frames or has no notes."""
    import mido

    p = Path(path)
    regular_file(p, "MIDI file", "a MIDI file")
    try:
        head = _header(p)
    except OSError as e:
        raise UsageError(f"cannot read MIDI file {p}: {e.strerror or e}") from None
    if head is not None:
        fmt, n_tracks, division = head
        if division & 0x8000:
            raise UsageError(f"{p} is timed in SMPTE frames ({256 - (division >> 8)} frames a second); only files "
                             f"timed in ticks per beat are read: save it with a tempo-based division")
        if division == 0:
            raise UsageError(f"{p} is not a standard MIDI file (its header gives 0 ticks per beat)")
    try:
        mid = mido.MidiFile(str(p))
    except (OSError, EOFError, ValueError, KeyError, IndexError, TypeError) as e:
        raise UsageError(f"{p} is not a standard MIDI file ({_why(e)})") from None
    if head is not None and len(mid.tracks) < n_tracks:
        present = p.read_bytes().count(b"MTrk")  # mido stops reading at the first missing one
        raise UsageError(f"{p} is truncated: its header announces {n_tracks} tracks, {present} are there")
    if mid.type == 2:
        raise UsageError(f"{p} is a type 2 MIDI file (independent sequences); only types 0 and 1 are read")
    if not any(len(t) for t in mid.tracks):
        raise UsageError(f"{p} is an empty MIDI file (no events)")
    piece = MidiPiece(p, mid.type, [])
    sounding: dict = {}  # (track, channel, note) -> (start, velocity)
    retriggered = unterminated = zero = 0
    t = 0.0
    try:
        events = _timed_events(mid)
    except (ValueError, KeyError, IndexError, TypeError, EOFError, ZeroDivisionError) as e:
        raise UsageError(f"{p} is not a readable MIDI file ({_why(e)})") from None

    def close(key, at):
        nonlocal zero
        start, vel = sounding.pop(key)
        if at > start:
            piece.notes.append(MidiNote(key[1], key[2], vel, start, at, key[0]))
        else:
            zero += 1

    for t, track, msg in events:
        kind = msg.type
        if kind == "note_on" and msg.velocity > 0:
            key = (track, msg.channel, msg.note)
            if key in sounding:
                retriggered += 1
                close(key, t)
            sounding[key] = (t, msg.velocity)
        elif kind == "note_off" or (kind == "note_on" and msg.velocity == 0):
            key = (track, msg.channel, msg.note)
            if key in sounding:
                close(key, t)
        elif kind == "control_change" and msg.control in (CC_PRESSURE, CC_EXPRESSION, CC_MODULATION):
            piece.controllers.setdefault((msg.channel, msg.control), []).append((t, msg.value))
        elif kind == "pitchwheel":
            piece.controllers.setdefault((msg.channel, BEND), []).append((t, msg.pitch + 8192))
    for key in list(sounding):
        unterminated += 1
        close(key, t)
    piece.length = t
    if not piece.notes:
        raise UsageError(f"{p} has no notes (no note-on with a velocity above 0 and a length)")
    tracks_of: dict = {}
    for n in piece.notes:
        tracks_of.setdefault(n.channel, set()).add(n.track)
    piece.notes = [MidiNote(n.channel, n.number, n.velocity, n.start, n.end, n.track,
                            channel_name(n.channel) if len(tracks_of[n.channel]) == 1
                            else f"t{n.track}-{channel_name(n.channel)}") for n in piece.notes]
    piece.notes.sort(key=lambda n: (n.start, n.channel, n.track, n.number))
    shared = sorted(ch + 1 for ch, trs in tracks_of.items() if len(trs) > 1)
    if shared:
        piece.remarks.append(f"channel(s) {', '.join(map(str, shared))} carry notes of several tracks: each track's "
                             f"part is its own voice (tT-chN)")
    if retriggered:
        piece.remarks.append(f"{retriggered} note(s) struck again while sounding in their voice: the first ends at "
                             f"the second")
    if unterminated:
        piece.remarks.append(f"{unterminated} note(s) without a note-off end at the end of the file ({t:.3f} s)")
    if zero:
        piece.remarks.append(f"{zero} note(s) of zero length dropped")
    return piece


def _why(e: Exception) -> str:
    if isinstance(e, EOFError):
        return "it ends early: truncated"
    return str(e) or type(e).__name__


def controller_curve(piece: MidiPiece, channel: int, cc, start: float, end: float,
                     max_points: int | None = MAX_POINTS) -> list[tuple[float, float]]:
    """The controller's values over [start, end] as breakpoints in seconds from `start` (a step is a CC_RAMP ramp):
    [(0, value)] when it does not change there."""
    events = piece.controllers.get((channel, cc), [])
    value = NEUTRAL[cc]
    for t, v in events:
        if t <= start:
            value = v
    pts = [(0.0, float(value))]
    for t, v in events:
        if start < t < end and v != pts[-1][1]:
            rel = t - start
            if rel > pts[-1][0]:
                pts.append((rel, pts[-1][1]))
            pts.append((rel + CC_RAMP, float(v)))
    # times strictly increasing: a change within a ramp of the last one replaces it
    out = [pts[0]]
    for t, v in pts[1:]:
        if t > out[-1][0]:
            out.append((t, v))
        else:
            out[-1] = (out[-1][0], v)
    return out if max_points is None else thin(out, max_points)


PITCH_STEP = 0.005  # s between a moving pitch curve's breakpoints (vibrato at 5.5 Hz: 36 a cycle, shape within 0.4 %)


def pitch_curve(piece: MidiPiece, channel: int, start: float, end: float, bend_range: float = BEND_RANGE):
    """The note's pitch as semitones from its written pitch over [start, end] (times from `start`), or None when it
    does not move: breakpoints of the bend (its ramps) and, while CC1 is above 0, every PITCH_STEP s of the vibrato
    (`bowsynth play` evaluates the same formula per window)."""
    bend = controller_curve(piece, channel, BEND, start, end, max_points=None)
    mod = controller_curve(piece, channel, CC_MODULATION, start, end, max_points=None)
    if len(bend) == 1 and bend[0][1] == NEUTRAL[BEND] and all(v == 0 for _, v in mod):
        return None
    import numpy as np

    from ..controls import Curve

    times = {0.0, end - start, *(t for t, _ in bend), *(t for t, _ in mod)}
    if any(v for _, v in mod):
        times.update(np.arange(0.0, end - start, PITCH_STEP).tolist())
    t = np.array(sorted(x for x in times if 0.0 <= x <= end - start))
    b = Curve(tuple(bend)).at(t)
    d = Curve(tuple(mod)).at(t)
    semis = np.array([bend_semitones(v, bend_range) for v in b]) + np.array([vibrato_depth(v) for v in d]) * np.sin(
        2.0 * np.pi * VIBRATO_HZ * t)
    return list(zip(t.tolist(), semis.tolist()))


def thin(points: list, max_points: int) -> list:
    """At most max_points breakpoints: repeatedly drop the inner point whose removal changes the curve least (a
    dense controller stream keeps its shape: the points where it turns). Times rounded to 0.1 ms."""
    pts = [(round(t, 4), float(v)) for t, v in points]
    while len(pts) > max_points:
        cost = [abs(pts[i][1] - (pts[i - 1][1] + (pts[i + 1][1] - pts[i - 1][1]) * (pts[i][0] - pts[i - 1][0])
                                 / (pts[i + 1][0] - pts[i - 1][0]))) for i in range(1, len(pts) - 1)]
        del pts[1 + cost.index(min(cost))]
    return pts


def channel_name(channel: int) -> str:
    return f"ch{channel + 1}"
