"""The sound to match: a mono recording read and checked (one channel, a usable rate and length, not clipped, not
silent, pitched), cut to the span the fit listens to."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf

from ..metrics import f0_estimate
from ..errors import UsageError

MIN_SECONDS = 0.25  # the onset and a few dozen periods of the lowest note
FIT_SECONDS = 2.0  # the span listened to: a note's onset and its sustain (longer targets are cut)
MIN_RATE, MAX_RATE = 8000, 384000
CLIP_LEVEL = 0.999  # of full scale
CLIP_RUN = 3  # consecutive samples at full scale: a clipped peak (a normalised file touches it once)
SILENT_PEAK = 1e-6
MIN_PITCH, MAX_PITCH = 20.0, 4000.0  # Hz: the pitches the shipped models sound at (f0 65-880 Hz and their ratios)


class FitError(UsageError):
    """A target the fit cannot read or use (exit 2), or a fit that found no match (FitMiss, exit 1)."""


class FitMiss(FitError):
    """The best match is not this instrument's sound: exit 1, nothing written unless forced."""

    exit_code = 1


DC_EDGE = 0.2  # s: a DC filter run backwards (a render's file, remove_dc) starts up in a signal's last 0.2 s


def dc_edge(n: int, sample_rate: float) -> int:
    """The samples at the end of a signal of n that the fit does not listen to for its pitch or check: the last
    DC_EDGE s; none in a signal shorter than 4 DC_EDGE."""
    return int(DC_EDGE * sample_rate) if n > 4 * DC_EDGE * sample_rate else 0


@dataclass
class Target:
    """A target's samples (float64, the first FIT_SECONDS), rate, pitch (Hz) and the signal it holds ('u' the mass's
    displacement, what renders write; 'p' its velocity, from a render's metadata)."""

    x: np.ndarray
    sample_rate: int
    pitch: float
    signal: str = "u"
    path: str = ""
    seconds: float = 0.0  # the whole file's length

    @property
    def n(self) -> int:
        return len(self.x)


def _signal_of(path: Path) -> str:
    """The signal a bowsynth render wrote ('u' or 'p', from its metadata); 'u' for any other file."""
    try:
        from ..io.audio import read_wav

        return "p" if read_wav(path).meta.get("signal") == "p" else "u"
    except Exception:  # noqa: BLE001 - a foreign file has no bowsynth metadata: a recording of u
        return "u"


def read_target(path) -> Target:
    """Read and check a target file; FitError (one line) where it cannot be fitted."""
    p = Path(path)
    if not p.is_file():
        raise FitError(f"{p}: no such file" if not p.exists() else f"{p} is not a regular file")
    try:
        info = sf.info(str(p))
        x, rate = sf.read(str(p), dtype="float64", always_2d=True)
    except (sf.LibsndfileError, RuntimeError, ValueError) as e:
        raise FitError(f"{p}: not an audio file soundfile reads ({str(e).splitlines()[0] if str(e) else 'unreadable'})"
                       ) from None
    if info.channels != 1:
        raise FitError(f"{p} has {info.channels} channels: fit takes a mono recording (one channel of it, or their "
                       f"mix)")
    if not MIN_RATE <= rate <= MAX_RATE:
        raise FitError(f"{p} is at {rate} Hz: fit takes {MIN_RATE}-{MAX_RATE} Hz")
    x = x[:, 0]
    seconds = len(x) / rate
    if seconds < MIN_SECONDS:
        raise FitError(f"{p} is {seconds:.3g} s long: fit needs at least {MIN_SECONDS:g} s (a note's onset and sustain)")
    if not np.all(np.isfinite(x)):
        raise FitError(f"{p} holds non-finite samples")
    peak = float(np.max(np.abs(x)))
    if peak < SILENT_PEAK:
        raise FitMiss(f"{p} is silent (peak {peak:.2g}): there is no sound to match")
    if peak >= CLIP_LEVEL:
        at = np.abs(x) >= CLIP_LEVEL
        run = np.convolve(at.astype(int), np.ones(CLIP_RUN, int), mode="valid")
        if np.any(run >= CLIP_RUN):
            raise FitError(f"{p} clips ({int(at.sum())} samples at full scale): its peaks are cut off, so its spectrum "
                           f"is not the instrument's; fit a recording that does not clip")
    x = x[:int(round(min(seconds, FIT_SECONDS) * rate))]
    edge = dc_edge(len(x), rate)
    pitch = f0_estimate(x[:len(x) - edge], rate)
    if not (math.isfinite(pitch) and MIN_PITCH <= pitch <= min(MAX_PITCH, rate / 8)):
        raise FitMiss(f"{p} has no steady pitch in its first {len(x) / rate:.3g} s: not a held note of this instrument")
    return Target(x=x, sample_rate=int(rate), pitch=float(pitch), signal=_signal_of(p), path=str(p), seconds=seconds)
