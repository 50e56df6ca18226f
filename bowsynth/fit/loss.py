"""How far a note sounds from the target, as a listener compares them: a multi-resolution spectral distance (auraloss)
at equal loudness, an onset term (the loudness envelope) and a pitch term (cents).

Both sounds enter above half the target's pitch (the bowed mass's static offset and the target's DC filter are not
sound), each scaled to unit RMS: levels are relative. The spectra's floor sits about 50 dB below the note's
fundamental (EPS), where the instrument's own targets stop counting harmonics: what lies under it (the FDM's -120 dB
between harmonics, the operator's -80 dB, a soft bow's tenth harmonic) is not heard beside the note and must not
steer the fit.
"""

from __future__ import annotations

import math

import numpy as np

from ..metrics import cents, f0_estimate
from .target import dc_edge

FFT_SIZES = (512, 1024, 2048)  # at 44.1 kHz (scaled with the rate): 12-46 ms, a few periods of the lowest notes
EPS = 1.0  # the spectra's power floor (auraloss eps), for signals of unit RMS: -50 dB re a 1024-point fundamental
FRAME_SECONDS = 0.01  # the onset term's loudness frames
FLOOR_DB = -60.0  # the envelope's floor, below the note's final level
ONSET_WEIGHT = 1.0  # per 20 dB of mean envelope difference
PITCH_CENTS = 10.0  # the pitch term: (cents / PITCH_CENTS)^2


def _sizes(sample_rate: float) -> list[int]:
    scale = sample_rate / 44100.0
    return [max(64, 2 ** round(math.log2(n * scale))) for n in FFT_SIZES]


def prepared(x, cut: int):
    """A sound as the loss takes it (torch): its content from FFT bin `cut` up (half the pitch), at unit RMS."""
    import torch

    X = torch.fft.rfft(x)
    keep = (torch.arange(X.shape[-1]) >= cut).to(X.real.dtype)
    d = torch.fft.irfft(X * keep, n=x.shape[-1])
    return d / (d.square().mean().sqrt() + 1e-30)


class SoundLoss:
    """The distance of candidate notes from one target (numpy samples at `sample_rate`, the target's signal)."""

    def __init__(self, target: np.ndarray, sample_rate: float):
        import auraloss
        import torch

        self.sample_rate = float(sample_rate)
        self.n = len(target)
        self.pitch_n = self.n - dc_edge(self.n, sample_rate)  # the pitch where the DC filter has settled
        self.pitch = f0_estimate(target[:self.pitch_n], sample_rate)
        sizes = _sizes(sample_rate)
        self.stft = auraloss.freq.MultiResolutionSTFTLoss(
            fft_sizes=sizes, hop_sizes=[s // 4 for s in sizes], win_lengths=sizes, eps=EPS)
        self.cut = int(0.5 * self.pitch * self.n / self.sample_rate) if math.isfinite(self.pitch) else 1
        self.y = prepared(torch.as_tensor(np.asarray(target, np.float64), dtype=torch.float32), self.cut)
        self.frame = max(8, int(round(FRAME_SECONDS * sample_rate)))
        self.env_y = self._envelope(self.y)

    def _envelope(self, d):
        import torch

        n = (len(d) // self.frame) * self.frame
        e = d[:n].reshape(-1, self.frame).square().mean(dim=1)
        final = e[-max(1, len(e) // 10):].mean()
        return 10 * torch.log10(e / final + 10 ** (FLOOR_DB / 10))

    def parts(self, x) -> dict:
        """The terms for a candidate's samples x (torch, the target's length): spectral and onset (torch, with the
        graph when x has one)."""
        d = prepared(x.to(self.y.dtype), self.cut)
        spectral = self.stft(d[None, None, :], self.y[None, None, :])
        onset = ONSET_WEIGHT * (self._envelope(d) - self.env_y).abs().mean() / 20.0
        return {"spectral": spectral, "onset": onset}

    def pitch_term(self, x: np.ndarray) -> tuple[float, float]:
        """(term, cents) of a candidate's pitch against the target's (numpy: measured, no gradient)."""
        c = cents(f0_estimate(np.asarray(x, float)[:self.pitch_n], self.sample_rate), self.pitch)
        return ((c / PITCH_CENTS) ** 2 if math.isfinite(c) else math.inf), c

    def sound(self, x: np.ndarray) -> float:
        """spectral + onset of a candidate (numpy samples), without a graph: what a curve's loss is."""
        import torch

        with torch.no_grad():
            p = self.parts(torch.as_tensor(np.asarray(x, np.float64), dtype=torch.float32))
        return float(p["spectral"] + p["onset"])

    def value(self, x: np.ndarray) -> float:
        """The whole loss of a candidate (numpy samples): spectral + onset + pitch."""
        return self.sound(x) + self.pitch_term(x)[0]
