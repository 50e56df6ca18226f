"""The pitch you hear: the f0 that makes a bowed note sound at a pitch, for the engine that plays it.

Friction lowers the pitch of the bowed mass: f0 100 Hz bowed with F_B 100, v_B 0.2 sounds at 91.33 Hz. In
dimensionless time (tau = w t) the motion depends on (beta = F_B / w, v_B, a) only, so the sounding frequency is
f0 * r(beta, v_B, a) with a ratio r that is the same at every pitch for the same beta. For a fixed bow force F_B,
beta itself depends on f0, so playing a written pitch P means solving

    f0 * r(F_B / (2 pi f0), v_B, a) = P

for f0: a 1-D root find (Brent) over log f0, each step a measurement of r by a short FDM run in tau (the same
scheme as `bowsynth.engines.fdm`, at w = 1). With beta held fixed instead (a model trained for one F_B / w plays every
pitch), f0 = P / r(beta) and F_B = beta w.

r is the frequency of the limit cycle the bow settles into from rest (the steady state), measured on the
displacement by interpolated zero crossings once amplitude and period have stopped moving, at two step sizes
combined by Richardson extrapolation (the scheme is second order). A note that settles on no oscillation (the bow
damps the mass: v_B below 1/sqrt(2a); or it grows too slowly: v_B near 0.3 at a = 100 and a weak bow) does not speak:
`SilentNoteError`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .. import physics
from .. import metrics
from ..errors import DomainError, SceneError, UsageError
from ..io.cache import DiskTable
from .notes import A4_HZ, parse_pitch


class SilentNoteError(SceneError):
    """A note that does not speak: from rest the bow settles on no oscillation (or takes too long to)."""


# --- the sounding ratio r(beta, v_B, a) ---------------------------------------------------------------------------

SPP = 1000  # FDM steps per free period 2 pi at the coarse step (the fine one halves it): see `sounding_ratio`
MAX_PERIODS = 2000  # a note still changing after this many free periods (1/f0) is reported as not speaking
AMP_TOL = 1e-4  # relative change of the amplitude between chunks: settled
FREQ_TOL = 2e-7  # relative change of the frequency between chunks: settled (3e-4 cents)
MEASURE_CHUNKS = 2  # chunks measured once settled


@dataclass(frozen=True)
class Ratio:
    """The steady state of a bowed note from rest, in dimensionless terms.

    r: sounding frequency / f0. settle_periods: free periods (of 1/f0) until amplitude and period are steady.
    amplitude: the limit cycle's half peak-to-peak of q = w u (m/s)."""

    r: float
    settle_periods: float
    amplitude: float
    beta: float
    vb: float
    a: float

    def settle_seconds(self, f0: float) -> float:
        return self.settle_periods / f0


def _steps_per_period(beta: float, a: float) -> int:
    # at least 20 steps inside the uniqueness step e / (beta sqrt(2a)); measured: the Richardson-combined r moves
    # < 1e-3 cents between 1000 and 4000 steps a period up to beta 3 at a 100
    kmax = physics.max_stable_step(beta, a)
    return int(max(SPP, math.ceil(20 * 2 * math.pi / kmax))) if math.isfinite(kmax) else SPP


class _Run:
    """The w = 1 FDM (beta, v_B, a) from rest, continued period block by period block."""

    def __init__(self, beta, vb, a, spp, k=None):
        from ..engines.fdm import taylor_start

        self.beta, self.vb, self.a, self.spp = beta, vb, a, spp
        self.k = 2 * math.pi / spp if k is None else k  # an engine's own step (spp then only sizes the blocks)
        self.state = (taylor_start(0.0, 0.0, self.k, 1.0, beta, vb, a), 0.0, -vb)
        self.u = []

    def more(self, periods: int) -> np.ndarray:
        from ..engines.fdm import run_fdm_raw

        n = periods * self.spp
        u, eta = run_fdm_raw(self.state[0], self.state[1], n + 1, 1, self.k, 1.0, self.beta, self.vb, self.a,
                             eta0=self.state[2])
        self.state = (u[n - 1], u[n], eta[n - 1])  # one step of overlap: the last two displacements seed the next
        self.u.append(u[:n])
        return u[:n]

    def r(self, first_period: int, last_period: int) -> float:
        """Sounding frequency / f0 over free periods [first, last), by interpolated zero crossings."""
        u = np.concatenate(self.u)[first_period * self.spp:last_period * self.spp]
        return 2 * math.pi * metrics.f0_estimate(u, 1.0 / self.k, tail=1.0)  # cycles per unit tau, as a rate


def _why_silent(beta, vb, a, amp_end, grows) -> str:
    sticky = 1.0 / math.sqrt(2.0 * a)
    if vb <= sticky:
        return (f"v_B = {vb:g} m/s is at or below 1/sqrt(2a) = {sticky:.3g} m/s, where the friction damps the mass "
                f"(a bow stop): bow faster")
    if grows:
        return (f"the oscillation grows too slowly (still {amp_end:.2g} m/s after {MAX_PERIODS} periods at "
                f"F_B / w = {beta:.4g}, v_B = {vb:g}): bow slower or press harder")
    if amp_end > 1e-3 * vb:
        return (f"no steady period within {MAX_PERIODS} periods at F_B / w = {beta:.4g}, v_B = {vb:g} (the motion "
                f"does not settle): press less hard, or raise the pitch")
    return f"the bow settles on no oscillation at F_B / w = {beta:.4g}, v_B = {vb:g}: bow slower or press harder"


# what the measurement depends on besides (beta, v_B, a): a change to any of it invalidates the on-disk table
RATIO_VERSION = f"5/{SPP}/{MAX_PERIODS}/{AMP_TOL!r}/{FREQ_TOL!r}/{MEASURE_CHUNKS}"
_ratios = DiskTable("sounding-ratio", RATIO_VERSION)


@functools.lru_cache(maxsize=4096)
def sounding_ratio(beta: float, vb: float, a: float = 100.0) -> Ratio:
    """r = sounding frequency / f0 of the note bowed from rest at (beta, v_B, a), once steady.

    Cached in the process and on disk (`bowsynth.io.cache`; a repeated `--pitch` costs no FDM run). Raises
    SilentNoteError when the note does not speak (see the module docstring); that answer is cached too."""
    beta, vb, a = float(beta), float(vb), float(a)
    for name, v in (("F_B / w", beta), ("v_B", vb), ("a", a)):
        if not math.isfinite(v):
            raise SceneError(f"{name} must be finite, got {v}")
    if beta < 0 or a <= 0:
        raise SceneError(f"need F_B / w >= 0 and a > 0, got {beta:g} and {a:g}")
    if beta == 0:
        raise SilentNoteError("the note does not speak: F_B = 0, no bow on the mass")
    key = f"{beta!r} {vb!r} {a!r}"
    hit = _ratios.get(key)
    if isinstance(hit, dict):
        if isinstance(hit.get("silent"), str):
            raise SilentNoteError(hit["silent"])
        try:
            got = Ratio(r=float(hit["r"]), settle_periods=float(hit["settle_periods"]),
                        amplitude=float(hit["amplitude"]), beta=beta, vb=vb, a=a)
            if 0 < got.r <= 1 and math.isfinite(got.settle_periods) and 0 <= got.settle_periods <= MAX_PERIODS \
                    and math.isfinite(got.amplitude) and got.amplitude >= 0:
                return got
        except (KeyError, TypeError, ValueError, OverflowError):
            pass  # an entry edited by hand, or of the wrong type or range: measure again
    try:
        ratio = measure_ratio(beta, vb, a)
    except SilentNoteError as e:
        _ratios.put(key, {"silent": str(e)})
        raise
    _ratios.put(key, {"r": ratio.r, "settle_periods": ratio.settle_periods, "amplitude": ratio.amplitude})
    return ratio


def measure_ratio(beta: float, vb: float, a: float, k: float | None = None) -> Ratio:
    """The steady ratio of the scheme run at steps 2 pi / spp and pi / spp combined by Richardson extrapolation (the
    truth), or, with k, of the scheme at that step in tau alone (an engine's own: the audio-rate FDM's dispersion)."""
    spp = _steps_per_period(beta, a) if k is None else max(4, int(round(2 * math.pi / k)))
    run = _Run(beta, vb, a, spp, k)
    # a chunk holds >= 10 sounding periods (the stick phase stretches a period to 6 free periods at beta 1.6)
    done = 0
    while done < MAX_PERIODS // 4:
        run.more(50)
        done += 50
        r0 = run.r(done // 2, done)
        if math.isfinite(r0) and r0 > 0:
            break
    chunk = int(max(20, math.ceil(10 / r0))) if math.isfinite(r0) and r0 > 0 else 20
    floor = 1e-3 * max(vb, 1e-3)  # below this the "oscillation" is the start's decaying ripple
    amps, freqs = [], []
    settled = None
    while done < MAX_PERIODS:
        u = run.more(chunk)
        amps.append(0.5 * (u.max() - u.min()))
        freqs.append(run.r(done, done + chunk))
        done += chunk
        if len(amps) >= 2:
            a0, a1, f0_, f1 = amps[-2], amps[-1], freqs[-2], freqs[-1]
            if (a1 > floor and abs(a1 / a0 - 1) < AMP_TOL and math.isfinite(f0_) and math.isfinite(f1)
                    and abs(f1 / f0_ - 1) < FREQ_TOL):
                settled = done - chunk
                break
    if settled is None:
        grows = len(amps) > 2 and amps[-1] > amps[-2] * (1 + AMP_TOL) and amps[-1] < 0.1 * vb
        raise SilentNoteError(f"the note does not speak: {_why_silent(beta, vb, a, amps[-1] if amps else 0, grows)}")
    end = settled + MEASURE_CHUNKS * chunk
    run.more(end - done)
    coarse = run.r(settled, end)
    if k is not None:
        return Ratio(r=float(coarse), settle_periods=float(settled), amplitude=float(amps[-1]), beta=beta, vb=vb, a=a)
    fine_run = _Run(beta, vb, a, 2 * spp)
    fine_run.more(end)
    fine = fine_run.r(settled, end)
    r = fine + (fine - coarse) / 3.0  # Richardson: the scheme's error is O(k^2)
    return Ratio(r=float(r), settle_periods=float(settled), amplitude=float(amps[-1]), beta=beta, vb=vb, a=a)


# --- solving for f0 ----------------------------------------------------------------------------------------------

PITCH_TOL_CENTS = 1e-3


@dataclass(frozen=True)
class Tuning:
    """The solved note: oscillator f0 and bow force fb that sound at `pitch` (Hz) with bow speed vb."""

    pitch: float
    f0: float
    fb: float
    vb: float
    a: float
    ratio: Ratio

    @property
    def beta(self) -> float:
        return physics.beta(self.fb, self.f0)

    @property
    def cents(self) -> float:
        """Solved residual: the sounding pitch f0 r against the asked one, in cents."""
        return metrics.cents(self.f0 * self.ratio.r, self.pitch)


def held_value(control, duration: float | None = None) -> float:
    """The value a bow control holds, to tune the note at: a number itself; a curve the median of its values over
    the note's first `duration` seconds (time-weighted: the value it holds when it holds one, the middle of a ramp
    that spans the note). See docs/score.md, "Pitch in gestures"."""
    from ..controls import Curve, as_control

    c = as_control(control)
    if not isinstance(c, Curve):
        return float(c)
    end = float(duration) if duration else float(c.times[-1])
    if end <= 0:
        return float(c.first)
    return float(np.median(c.at(np.linspace(0.0, end, 4001))))


def tune(pitch, fb: float | None = 100.0, vb: float = 0.2, a: float = 100.0, *, beta: float | None = None,
         a4: float = A4_HZ, ratio=None, physics_ratio=None) -> Tuning:
    """Solve for the oscillator f0 that sounds at `pitch` (Hz or a note name) when bowed with force fb (held
    fixed) or, with `beta` given instead, with the force that keeps F_B / w = beta (fb = beta 2 pi f0).

    ratio: the engine that will play the note, as a function (beta, v_B, a, f0) -> sounding ratio (`fdm_ratio`,
    `operator_ratio` below); None: the physics' own. physics_ratio: where the physics' ratio comes from, a function
    (beta, v_B, a) -> Ratio: None for the ratio's own `physics` attribute if it has one (an operator's ratio carries the
    shipped map, `ratio_map.physics_ratio`: no reference at render time), else sounding_ratio (the reference, which
    `compare` scores against)."""
    p = parse_pitch(pitch, a4)
    source = physics_ratio or getattr(ratio, "physics", None) or sounding_ratio
    vb, a = float(vb), float(a)
    if ratio is not None:
        return _tune_with(p, fb, vb, a, beta, ratio, source)
    if beta is not None:
        if fb is not None:
            raise UsageError("give the bow force as fb or as beta (F_B / w), not both")
        rat = source(float(beta), vb, a)
        f0 = p / rat.r
        return Tuning(p, f0, float(beta) * physics.omega(f0), vb, a, rat)
    if fb is None:
        raise UsageError("give the bow force as fb or as beta (F_B / w)")
    fb = float(fb)
    if fb == 0:
        return Tuning(p, p, 0.0, vb, a, Ratio(1.0, 0.0, 0.0, 0.0, vb, a))  # the free oscillator: r = 1

    def ratio(f0):
        return source(physics.beta(fb, f0), vb, a)

    def h(logf):  # cents from the asked pitch; increasing in f0 (a lighter beta sounds nearer f0)
        f0 = math.exp(logf)
        return metrics.cents(f0 * ratio(f0).r, p)

    # friction only lowers the pitch (r <= 1) and lowers it less at a smaller beta: [p, p / r(beta(p))] brackets
    lo = math.log(p)
    hi = lo - math.log(ratio(p).r)
    h_lo, h_hi = h(lo), h(hi)
    for _ in range(40):
        if h_lo <= 0 <= h_hi:
            break
        if h_lo > 0:
            lo -= 0.05
            h_lo = h(lo)
        if h_hi < 0:
            hi += max(hi - lo, 0.05)
            h_hi = h(hi)
    else:
        raise UsageError(f"found no f0 that sounds at {p:g} Hz with F_B = {fb:g}, v_B = {vb:g}, a = {a:g}")
    if abs(h_lo) < PITCH_TOL_CENTS or abs(h_hi) < PITCH_TOL_CENTS:
        x = lo if abs(h_lo) < abs(h_hi) else hi
    else:
        x = _bracketed_root(h, lo, hi, h_lo, h_hi)
    f0 = math.exp(x)
    return Tuning(p, f0, fb, vb, a, ratio(f0))


def _bracketed_root(h, lo: float, hi: float, h_lo: float, h_hi: float, xtol: float = 1e-9) -> float:
    """The root of an increasing h in [lo, hi] (h_lo <= 0 <= h_hi) by false position with the Illinois step, to xtol
    in log f0 (1.7e-6 cents) or |h| < PITCH_TOL_CENTS / 1000. Written here rather than scipy's brentq: importing
    scipy.optimize took 0.5 s of a 1 s note's whole process (1.7 s on a loaded machine), for a 1-D root."""
    side = 0
    for _ in range(200):
        x = (lo * h_hi - hi * h_lo) / (h_hi - h_lo)
        hx = h(x)
        if abs(hx) < PITCH_TOL_CENTS / 1000 or hi - lo < xtol:
            return x
        if hx < 0:
            lo, h_lo = x, hx
            if side == -1:
                h_hi /= 2  # the same end moved twice: halve the other's weight, or false position crawls
            side = -1
        else:
            hi, h_hi = x, hx
            if side == 1:
                h_lo /= 2
            side = 1
    return x


def _tune_with(p: float, fb, vb: float, a: float, beta, ratio, source) -> Tuning:
    """tune() with an engine's ratio: the secant method on the cents error over log f0, from the truth's solution
    (the engine's ratio differs from the truth's by cents), to PITCH_TOL_CENTS. Not a fixed-point iteration: in
    stick-slip r falls like 1 / beta, and f0 = pitch / r(f0) would not converge."""
    if beta is not None and fb is not None:
        raise UsageError("give the bow force as fb or as beta (F_B / w), not both")
    first = tune(p, fb, vb, a, beta=beta, physics_ratio=source)

    def err(x):  # cents from the asked pitch at f0 = e^x
        f0 = math.exp(x)
        b = float(beta) if beta is not None else physics.beta(float(fb), f0)
        return metrics.cents(f0 * ratio(b, vb, a, f0), p)

    x0 = math.log(first.f0)
    e0 = err(x0)
    x1 = x0 - e0 * math.log(2) / 1200  # slope 1 in cents per cent of f0 where r does not move with f0
    best = (abs(e0), x0)
    for _ in range(12):
        e1 = err(x1)
        best = min(best, (abs(e1), x1))
        if abs(e1) < PITCH_TOL_CENTS or e1 == e0:
            break
        x0, e0, x1 = x1, e1, x1 - e1 * (x1 - x0) / (e1 - e0)
    f0 = math.exp(best[1])
    force = float(beta) * physics.omega(f0) if beta is not None else float(fb)
    b = physics.beta(force, f0)
    return Tuning(p, f0, force, vb, a, Ratio(ratio(b, vb, a, f0), first.ratio.settle_periods, first.ratio.amplitude,
                                             b, vb, a))


def f0_for_pitch(pitch, fb: float | None = 100.0, vb: float = 0.2, a: float = 100.0, *,
                 beta: float | None = None, a4: float = A4_HZ, ratio=None) -> float:
    """The oscillator f0 (Hz) that sounds at `pitch` (Hz or a note name) with bow force fb (m/s^2) and speed vb
    (m/s); with `beta` instead of fb, the force scales with f0 (fb = beta 2 pi f0). See `tune`."""
    return tune(pitch, fb, vb, a, beta=beta, a4=a4, ratio=ratio).f0


def sounding_pitch(f0: float, fb: float, vb: float = 0.2, a: float = 100.0) -> float:
    """The steady pitch (Hz) a note at oscillator f0 sounds at with this bow (raises SilentNoteError if none)."""
    if fb == 0:
        return float(f0)
    return f0 * sounding_ratio(physics.beta(fb, f0), vb, a).r


