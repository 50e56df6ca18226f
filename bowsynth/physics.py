"""The bowed mass: friction law, ODE (physical and dimensionless), energy, scalings.

The single source of truth for the physics; the FDM, the training losses and the metrics import it.

    u_tt + w^2 u = -F_B phi(u_t - v_B),   phi(eta) = sqrt(2a) eta exp(-a eta^2 + 1/2)

State (q, p) = (w u, u_t), both in m/s. In dimensionless time tau = w t:
    q' = p,  p' = -q - beta phi(p - v_B),  beta = F_B / w.
Functions work on floats, numpy arrays and torch tensors alike (they only use arithmetic and `exp`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

E_HALF = math.exp(0.5)
# the implicit friction solve of each FDM step (Newton on eta = relative velocity), in both FDM loops
NEWTON_TOL = 1e-14  # absolute, m/s: eta is O(0.1-1)
NEWTON_MAXIT = 60


def _exp(x):
    # torch tensors carry their own exp (keeps autograd); a Python float
    # takes math.exp, ~10x faster than np.exp on a scalar (the render-time physics check steps in Python floats)
    if type(x) is float:
        return math.exp(x)
    return x.exp() if hasattr(x, "exp") else np.exp(x)


# The friction's slope at rest in dimensionless time, beta sqrt(2a) e^{1/2}, above which a bow plays stick-slip: 10
# (beta 0.43 at a = 100) is the soft / stick-slip boundary the models are split by. Training drops the friction
# residual above it (training.losses); the operator computes such voices on whole windows (engines.operator.grid).
STIFF = 10.0


def stiffness(beta: float, a: float) -> float:
    """The friction's slope at rest in dimensionless time, beta sqrt(2a) e^{1/2}."""
    return beta * math.sqrt(2 * a) * E_HALF


def omega(f0: float) -> float:
    """Angular frequency w = 2 pi f0 (rad/s)."""
    return 2.0 * math.pi * f0


def beta(fb: float, f0: float) -> float:
    """Dimensionless bow force beta = F_B / w: with v_B and a, it fixes the dimensionless dynamics."""
    return fb / omega(f0)


def dtau(f0: float, sample_rate: float) -> float:
    """Spacing of audio samples in dimensionless time tau = w t."""
    return omega(f0) / sample_rate


def phi(eta, a: float):
    """Soft friction law; |phi| <= 1, reached at |eta| = 1/sqrt(2a)."""
    return math.sqrt(2.0 * a) * eta * _exp(-a * eta * eta + 0.5)


def dphi(eta, a: float):
    """d phi / d eta; its minimum is -2 sqrt(2a) / e at eta^2 = 3 / (2a)."""
    return math.sqrt(2.0 * a) * _exp(-a * eta * eta + 0.5) * (1.0 - 2.0 * a * eta * eta)


# A note whose p over its last half has RMS below this (m/s; notes play at 0.05-0.6) is silence: bench map's rule,
# validation's where the truth rests (analysis.metrics.note_sounds) and the ring-down's (engines/operator/onset.py)
SILENT = 1e-4


def vb_stop(a: float) -> float:
    """The bow speed below which friction damps the mass instead of driving it (phi' > 0 at -v_B): 1 / sqrt(2a)."""
    return 1.0 / math.sqrt(2.0 * a)


def onset_rate(b: float, vb: float, a: float):
    """Growth rate per unit tau of small oscillations about the rest state: -beta phi'(-v_B) / 2. Positive: the note
    speaks by itself; negative or zero: the bow damps the mass (below v_B = 1/sqrt(2a) phi' > 0, a bow stop)."""
    return -0.5 * b * dphi(-vb, a)


def growth_tau(rate, offset, scale):
    """tau for an oscillation growing at `rate` (onset_rate) to go from `offset` (its distance from the rest state at
    the start) to `scale`: log(scale / offset) / rate, 0 where it starts that large (where rate > 0; numpy arrays
    too). The two onset rules (training.ranges.speaks, engines.operator.onset.speak_time) differ only in the scale."""
    if type(rate) is float and type(offset) is float and type(scale) is float:  # a render's note: math, as _exp
        return math.log(max(scale / max(offset, 1e-300), 1.0)) / rate
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.maximum(np.asarray(scale, float) / np.maximum(offset, 1e-300), 1.0)) / rate


def rhs_tau(q, p, b: float, vb: float, a: float):
    """(dq/dtau, dp/dtau) in dimensionless time tau = w t, with b = beta = F_B / w."""
    return p, -q - b * phi(p - vb, a)


def linear_flow(q0, p0, tau, lin=None):
    """Exact flow of the frictionless oscillator: a rotation of (q, p) by tau. With lin = (d, q_s) (see
    `rest_linearisation`), the exact flow of the bowed oscillator linearised at its rest state instead."""
    m11, m12, m21, m22, k_q, k_p = flow_coefficients(tau, lin)
    return m11 * q0 + m12 * p0 + k_q, m21 * q0 + m22 * p0 + k_p


def rest_linearisation(b: float, vb: float, a: float) -> tuple[float, float]:
    """(d, q_s): the bowed mass near its rest state (q_s, 0) moves as q' = p, p' = -(q - q_s) - d p, with
    d = beta phi'(-v_B) (negative where the bow drives the mass: the oscillation grows at -d / 2 per unit tau) and
    q_s = beta phi(v_B)."""
    return b * dphi(-vb, a), b * phi(vb, a)


# |d| of the linearisation a point model's network may carry in its output (--rest-linear: its window basis is the
# underdamped flow's); the rest flow of the renderers takes any d (flow_coefficients)
MAX_REST_DAMPING = 1.9

# How far the friction's slope phi' may move from its value at rest over a swing of the relative velocity before the
# flow linearised at rest stops describing the mass (rest_radius). Measured (eight slow-corner bows at
# 66-714 Hz, 2 s from rest: the exact linear flow to the radius, then the operator, against a x100 FDM): onsets
# within 5.0 ms of the truth's 0.2-1.9 s at 0.2, within 22 ms at 0.1 and 33 ms at 0.4; the operator alone 2-700 ms.
REST_TOL = 0.2


@functools.lru_cache(maxsize=4096)
def rest_radius(vb: float, a: float, tol: float = REST_TOL) -> float:
    """The swing |(q - q_s, p)| within which the flow linearised at the rest state holds: phi' stays within tol
    (relative) of phi'(-v_B) over relative velocities -v_B +- the swing. 0 where phi'(-v_B) = 0 (no linear flow)."""
    d0 = dphi(-vb, a)
    if not d0 or not math.isfinite(d0):
        return 0.0

    def off(u):
        return max(abs(dphi(-vb + u, a) / d0 - 1.0), abs(dphi(-vb - u, a) / d0 - 1.0)) > tol
    lo, hi = 0.0, 1e-4
    while not off(hi):  # the slope moves on the scale 1 / (a v_B): a few dozen growing steps find the crossing
        lo, hi = hi, hi * 1.25
        if hi > 10.0:
            return lo
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if off(mid) else (mid, hi)
    return lo


def rest_flow(b: float, vb: float, a: float, q: float, p: float):
    """(d, q_s, radius) where the state (q, p) lies within the radius of the bow's rest state (the exact flow
    linearised at rest plays it: engines/operator/onset.py); else None."""
    d, qs = rest_linearisation(b, vb, a)
    if not math.isfinite(d):
        return None
    r = rest_radius(float(vb), float(a))
    return (d, qs, r) if (q - qs) ** 2 + p * p <= r * r else None


def flow_coefficients(tau, lin=None):
    """(m11, m12, m21, m22, k_q, k_p) at times tau: the linear flow is x(tau) = M x0 + k. lin None: the rotation
    (k = 0); lin = (d, q_s): M = exp(A tau) with A = [[0, 1], [-1, -d]] and k = (I - M) (q_s, 0), for any d: an
    underdamped bow (|d| < 2) oscillates, an overdamped one (a heavy bow below vb_stop: d up to ~30) creeps, its
    two real modes' exponentials kept apart (cosh alone would overflow). The core's rest_coefficients is the same."""
    tau = np.asarray(tau, dtype=float)
    if lin is None:
        c, s = np.cos(tau), np.sin(tau)
        z = np.zeros_like(tau)
        return c, s, -s, c, z, z
    d, qs = lin
    if not math.isfinite(d):
        raise ValueError(f"the rest-state linearisation needs a finite d, got d = {d:g}")
    z = 1.0 - 0.25 * d * d
    if z >= 0.0:
        wd = math.sqrt(max(z, 1e-30))
        e = np.exp(-0.5 * d * tau)
        ec, es = e * np.cos(wd * tau), e * np.sin(wd * tau) / wd
    else:
        wd = math.sqrt(-z)
        slow, fast = np.exp((wd - 0.5 * d) * tau), np.exp((-wd - 0.5 * d) * tau)
        ec, es = 0.5 * (slow + fast), 0.5 * (slow - fast) / wd
    m11, m12, m21, m22 = ec + 0.5 * d * es, es, -es, ec - 0.5 * d * es
    return m11, m12, m21, m22, qs * (1.0 - m11), -qs * m21


def energy(q, p):
    """Energy per unit mass, (u_t^2 + w^2 u^2) / 2 = (p^2 + q^2) / 2 (J/kg)."""
    return 0.5 * (q * q + p * p)


def friction_power(p, fb: float, vb: float, a: float):
    """Power per unit mass done by the bow on the mass: dE/dt = -F_B phi(p - v_B) p."""
    return -fb * phi(p - vb, a) * p


def max_stable_step(fb: float, a: float) -> float:
    """Largest time step for which Bilbao's scheme has a unique solution: k < e / (F_B sqrt(2a))."""
    if fb <= 0:
        return math.inf
    return math.e / (fb * math.sqrt(2.0 * a))


def max_linear_step(w: float) -> float:
    """Largest time step for which the scheme's undamped oscillator is stable: k < 2 / w (Bilbao's bound for the
    centred difference of u_tt + w^2 u). Beyond it (f0 above sample_rate / pi, 14 kHz at 44.1 kHz) the render blows up."""
    return 2.0 / w


def min_oversample(fb: float, a: float, sample_rate: float, f0: float | None = None) -> int:
    """Smallest integer oversampling factor that keeps the FDM step below the uniqueness bound (and, given f0,
    below the oscillator's stability bound).

    A 1 % safety margin keeps the Newton solve well conditioned right at the bound.
    """
    kmax = 0.99 * max_stable_step(fb, a)
    if f0 is not None:
        kmax = min(kmax, 0.99 * max_linear_step(omega(f0)))
    if math.isinf(kmax):
        return 1
    return max(1, math.ceil(1.0 / (sample_rate * kmax)))
