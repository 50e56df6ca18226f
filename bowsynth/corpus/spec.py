"""A corpus's spec (TOML: how many notes, their ranges, the share of gestures, the seed) and the notes it draws.

    count = 2000           # notes
    seed = 1
    duration = 2.0         # s, each note from rest
    sample_rate = 44100
    f0 = [65, 880]         # Hz, log-uniform
    beta = [0.02, 2.0]     # F_B / w, log-uniform
    vb = [0.08, 0.28]      # m/s, uniform
    gestures = 0.25        # the share whose bow moves: a crescendo, a bow-speed change or a bow stop

Note i is drawn from its own generator (seed, i), so a corpus of 2000 holds the 50 of a corpus of 50 from the same
seed, and a rerun draws the same notes. A drawn bow that does not sound, or that no shipped model covers over its
whole gesture, is drawn again (the same way on every run).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import UsageError

KEYS = {"count", "seed", "duration", "sample_rate", "f0", "beta", "vb", "gestures"}
DEFAULTS = {"count": 100, "seed": 1, "duration": 2.0, "sample_rate": 44100, "f0": [65.0, 880.0],
            "beta": [0.02, 2.0], "vb": [0.08, 0.28], "gestures": 0.0}
MAX_COUNT = 10_000_000
KINDS = ("crescendo", "speed", "stop")


class SpecError(UsageError):
    """A spec that cannot be drawn from (one line, exit 2)."""


@dataclass
class Spec:
    count: int
    seed: int
    duration: float
    sample_rate: int
    f0: tuple
    beta: tuple
    vb: tuple
    gestures: float
    source: str = ""

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in sorted(KEYS)}


@dataclass
class NoteSpec:
    """One note of a corpus: its index, kind ('held' or a gesture), f0, and its bow (numbers, or [[t, value], ...])
    as F_B (m/s^2) and v_B, with the held values' F_B / w and v_B for labels."""

    index: int
    kind: str
    f0: float
    fb: object
    vb: object
    beta: float
    vb_held: float
    labels: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.index:07d}"


def _range(name: str, v, lo_ok: float, hi_ok: float) -> tuple[float, float]:
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                       for x in v)):
        raise SpecError(f"{name} must be [low, high], got {v!r}")
    lo, hi = float(v[0]), float(v[1])
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise SpecError(f"{name} must be finite, got {v!r}")
    if lo > hi:
        raise SpecError(f"{name} is an empty range: {lo:g} > {hi:g}")
    if lo < lo_ok or hi > hi_ok:
        raise SpecError(f"{name} must lie within [{lo_ok:g}, {hi_ok:g}], got [{lo:g}, {hi:g}]")
    return lo, hi


def parse_spec(data: dict, source: str = "") -> Spec:
    unknown = set(data) - KEYS
    if unknown:
        raise SpecError(f"unknown key(s) in {source or 'the spec'}: {', '.join(sorted(unknown))} "
                        f"(known: {', '.join(sorted(KEYS))})")
    d = dict(DEFAULTS, **data)
    for k in ("count", "seed", "sample_rate"):
        if isinstance(d[k], bool) or not isinstance(d[k], int):
            raise SpecError(f"{k} must be a whole number, got {d[k]!r}")
    if not 1 <= d["count"] <= MAX_COUNT:
        raise SpecError(f"count must be 1-{MAX_COUNT}, got {d['count']}")
    if not 8000 <= d["sample_rate"] <= 384000:
        raise SpecError(f"sample_rate must be 8000-384000 Hz, got {d['sample_rate']}")
    dur = d["duration"]
    if isinstance(dur, bool) or not isinstance(dur, (int, float)) or not 0.05 <= dur <= 60:
        raise SpecError(f"duration must be 0.05-60 s, got {dur!r}")
    g = d["gestures"]
    if isinstance(g, bool) or not isinstance(g, (int, float)) or not 0 <= g <= 1:
        raise SpecError(f"gestures must be a share 0-1, got {g!r}")
    f0 = _range("f0", d["f0"], 20.0, d["sample_rate"] / 8)
    return Spec(d["count"], d["seed"], float(dur), d["sample_rate"], f0, _range("beta", d["beta"], 0.005, 2.02),
                _range("vb", d["vb"], 0.0, 0.3), float(g), source)


def read_spec(path) -> Spec:
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SpecError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SpecError(f"{p}: {getattr(e, 'strerror', None) or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{p}: not valid TOML ({e})") from None
    return parse_spec(data, str(p))


def _log_uniform(rng, lo, hi) -> float:
    return float(lo if lo == hi else math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _uniform(rng, lo, hi) -> float:
    return float(lo if lo == hi else rng.uniform(lo, hi))


def draw_note(spec: Spec, i: int, playable, tries: int = 200) -> NoteSpec:
    """Note i of the corpus: drawn from generator (seed, i) until `playable(note)` (a bow that sounds and that a
    model covers)."""
    rng = np.random.default_rng([spec.seed, i])
    T = spec.duration
    for _ in range(tries):
        f0 = _log_uniform(rng, *spec.f0)
        beta = _log_uniform(rng, *spec.beta)
        vb = _uniform(rng, *spec.vb)
        kind = "held" if rng.uniform() >= spec.gestures else KINDS[int(rng.integers(len(KINDS)))]
        w = 2 * math.pi * f0
        if kind == "crescendo":  # F_B / w from a third to the drawn value over the note
            fb, vbc = [[0.0, beta * w / 3], [T, beta * w]], vb
        elif kind == "speed":  # v_B from the drawn value to the range's other end
            other = spec.vb[1] if vb < sum(spec.vb) / 2 else spec.vb[0]
            fb, vbc = beta * w, [[0.0, vb], [T, other]]
        elif kind == "stop":  # held, then stopped over the last quarter
            fb, vbc = beta * w, [[0.0, vb], [0.6 * T, vb], [0.85 * T, 0.0]]
        else:
            fb, vbc = beta * w, vb
        note = NoteSpec(i, kind, f0, fb, vbc, beta, vb)
        if playable(note):
            return note
    raise SpecError(f"note {i}: no playable bow in {tries} draws from these ranges (widen beta or vb)")
