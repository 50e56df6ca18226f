"""Note names and equal temperament: MIDI numbers, names such as "F#3" and pitches in Hz, at a chosen A4."""

from __future__ import annotations

import math
import re

from ..errors import UsageError

A4_HZ = 440.0
A4_MIDI = 69
A4_RANGE = (100.0, 1000.0)  # a reference outside this is a typo, not a tuning
LOWEST, HIGHEST = "C0", "B8"  # the named range: 16.35 Hz to 7902 Hz at A4 = 440 (scientific pitch notation)
LOWEST_MIDI, HIGHEST_MIDI = 12, 119
_STEPS = {"C": 0, "D": 2, "E": 4, "F": 5, "G": 7, "A": 9, "B": 11}
_ACCIDENTALS = {"": 0, "#": 1, "♯": 1, "b": -1, "♭": -1, "##": 2, "x": 2, "bb": -2}
_NOTE_RE = re.compile(r"^([A-Ga-g])(##|bb|#|b|x|♯|♭|)(-?\d+)$")
_NAMES = ["C", "C#", "D", "D#", "E", "F", "F#", "G", "G#", "A", "A#", "B"]


def check_a4(a4: float) -> float:
    if isinstance(a4, bool) or not isinstance(a4, (int, float)) or not math.isfinite(a4):
        raise UsageError(f"--a4 must be a number of Hz, got {a4!r}")
    if not A4_RANGE[0] <= a4 <= A4_RANGE[1]:
        raise UsageError(f"--a4 must be in [{A4_RANGE[0]:g}, {A4_RANGE[1]:g}] Hz, got {a4:g}")
    return float(a4)


def midi_to_hz(note: float, a4: float = A4_HZ) -> float:
    """Equal temperament: MIDI note 69 is A4 = a4 Hz, 12 notes an octave."""
    return float(a4 * 2.0 ** ((note - A4_MIDI) / 12.0))


def hz_to_midi(hz: float, a4: float = A4_HZ) -> float:
    return float(A4_MIDI + 12.0 * math.log2(hz / a4))


def note_number(name: str) -> int:
    """MIDI note number of a note name in scientific pitch notation: A4 = 69, C4 = 60 (middle C), Bb2, C#3, F##5.

    The octave number goes with the letter, as in the notation: Cb4 is B3, B#3 is C4. Names from C0 to B8 only."""
    m = _NOTE_RE.match(name.strip()) if isinstance(name, str) else None
    if not m and isinstance(name, str) and name.strip()[:1] in ("H", "h"):
        raise UsageError(f"{name!r} is not a note name here: the German H is B (write B{name.strip()[1:]})")
    if not m:
        raise UsageError(f"{name!r} is not a note name: a letter A-G, an optional # or b, an octave number "
                         f"(A4, C#3, Bb2), from {LOWEST} to {HIGHEST}")
    letter, acc, octave = m.group(1).upper(), m.group(2), int(m.group(3))
    n = 12 * (octave + 1) + _STEPS[letter] + _ACCIDENTALS[acc]
    if not LOWEST_MIDI <= n <= HIGHEST_MIDI:
        raise UsageError(f"note {name!r} is outside {LOWEST}..{HIGHEST} (16.35 Hz to 7902 Hz)")
    return n


def note_name(hz: float, a4: float = A4_HZ) -> str:
    """The nearest note and the distance to it, e.g. 'F#2 -23.4 cents'."""
    m = hz_to_midi(hz, a4)
    n = int(round(m))
    c = 100.0 * (m - n)
    name = f"{_NAMES[n % 12]}{n // 12 - 1}"
    return name if abs(c) < 0.05 else f"{name} {c:+.1f} cents"


def parse_pitch(value, a4: float = A4_HZ) -> float:
    """A pitch in Hz from a number (Hz), a numeric string ('440', '261.6') or a note name ('A4', 'C#3', 'Bb2')."""
    a4 = check_a4(a4)
    if isinstance(value, bool):
        raise UsageError(f"pitch must be Hz or a note name, got {value!r}")
    if isinstance(value, str):
        s = value.strip()
        try:
            hz = float(s)
        except ValueError:
            return midi_to_hz(note_number(s), a4)
    elif isinstance(value, (int, float)):
        hz = float(value)
    else:
        raise UsageError(f"pitch must be Hz or a note name, got {value!r}")
    lo, hi = midi_to_hz(LOWEST_MIDI, a4), midi_to_hz(HIGHEST_MIDI, a4)
    if not math.isfinite(hz) or not lo * 0.999 <= hz <= hi * 1.001:
        raise UsageError(f"pitch must be between {LOWEST} ({lo:.2f} Hz) and {HIGHEST} ({hi:.0f} Hz), got {value!r}")
    return hz
