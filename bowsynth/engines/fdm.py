"""Finite-difference reference solver: Bilbao's scheme for the bowed mass, Newton on the relative velocity.

    (u^{n+1} - 2u^n + u^{n-1}) / k^2 + w^2 u^n = -F_B phi(eta^n),   eta^n = (u^{n+1} - u^{n-1}) / (2k) - v_B

Each step solves (2/k) eta + F_B phi(eta) + b = 0 for eta by a bracketed Newton iteration, then
u^{n+1} = u^{n-1} + 2k (eta + v_B). Output at sample n: q = w u^n and p = eta^n + v_B (the centred velocity).

Start convention: the ghost value u^{-1} is chosen so that the centred velocity at n = 0 is exactly p0, i.e.
u^{+-1} = u^0 +- k p0 - k^2/2 (w^2 u^0 + F_B phi(p0 - v_B)) -- the second-order Taylor start. So q[0] = q0,
p[0] = p0, and the render converges at second order to the initial-value problem. The paper's own file instead uses
u^{-1} = u^0 = 0 (see `run_fdm_raw`).

Two paths: the compiled loop of `bowsynth.compiled` (src/core/fdm.cpp: `render_fdm`, one voice, and `fdm_batch`'s
default, many states for training data, over threads) and numpy (`fdm_batch(loop="numpy")`, vectorised across the
states: the readable reference the tests hold the compiled loop to). They run the same iteration and agree to the
bit.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from .. import physics
from ..errors import SceneError
from ..render import Played, Render, RenderInfo
from ..scene import Scene

# the truth every accuracy figure is measured against: this FDM at 100x the sample rate (docs/measures.md)
TRUTH_OVERSAMPLE = 100
MAX_OVERSAMPLE = 1024  # beyond this a render would run for minutes to hours: refuse instead
DENSE_BELOW = 512  # states: below this `_solve_eta_vec` iterates densely (see _solve_eta_dense)
CHUNK_STEPS = 2_000_000  # scheme steps per compiled call (see run_fdm_raw)


class OversampleWarning(UserWarning):
    """The FDM raised its oversampling to respect the uniqueness bound."""


def taylor_start(u0, p0, k, w, fb, vb, a):
    """Ghost value u^{-1} that makes the scheme's centred velocity at n = 0 equal p0 (works on arrays)."""
    return u0 - k * p0 - 0.5 * k * k * (w * w * u0 + fb * physics.phi(p0 - vb, a))


def _squared(w):
    """w^2 for the compiled step: a number squared, or a w Curve as a w^2 Curve (see run_fdm_raw)."""
    from ..controls import Curve

    if not isinstance(w, Curve):
        return float(w) * float(w)
    pts = [w.points[0]]
    for (t0, w0), (t1, w1) in zip(w.points, w.points[1:]):
        # linear w, squared, against linear w^2 over a piece: they differ by (dw / 2)^2 at its middle at most
        pieces = 1 if t1 <= t0 else max(1, math.ceil(abs(w1 - w0) / (2e-5 * max(min(abs(w0), abs(w1)), 1e-9))))
        pts += [(t0 + (t1 - t0) * i / pieces, w0 + (w1 - w0) * i / pieces) for i in range(1, pieces + 1)]
    return Curve(tuple((t, v * v) for t, v in pts))


def run_fdm_raw(u_prev, u_cur, n_out, stride, k, w, fb, vb, a, eta0=None, w2=None):
    """The bare scheme from two given displacements (u^{-1}, u^0): returns (u, eta) at every `stride`-th step.

    w (rad/s), fb and vb are numbers or Curves (followed per step, from t = 0 at u^0); w2, if given, replaces w * w:
    a number or a Curve of the squared angular frequency (rad^2/s^2). A w Curve is linear in w between its
    breakpoints (a pitch that moves), as the scheme wants it; the compiled step follows w^2 piecewise linearly, so
    each segment is cut finely enough that the two differ by less than 1e-10 of w^2 (1e-4 cents)."""
    from ..controls import breakpoints
    from .. import compiled as core

    u_out = np.empty(n_out)
    eta_out = np.empty(n_out)
    w2_t, w2_v = breakpoints(_squared(w) if w2 is None else w2)
    fb_t, fb_v = breakpoints(fb)
    vb_t, vb_v = breakpoints(vb)
    eta = -vb_v[0] if eta0 is None else eta0
    state = (float(u_prev), float(u_cur), float(eta))
    # chunks of CHUNK_STEPS steps (~0.1-0.3 s each): Python runs signal handlers (Ctrl-C, SIGTERM) only between
    # compiled calls, and a 20 s x200 render in one call ignored Ctrl-C for 13 s
    per = max(1, CHUNK_STEPS // int(stride))
    for j in range(0, int(n_out), per):
        m = min(per, int(n_out) - j)
        state = core.fdm_run(*state, j * int(stride), m, int(stride), float(k), w2_t, w2_v, fb_t, fb_v, vb_t, vb_v,
                             float(a), physics.NEWTON_TOL, physics.NEWTON_MAXIT, u_out[j:j + m], eta_out[j:j + m])
    return u_out, eta_out


def check_oversample(scene: Scene, oversample: int, warn: bool = True) -> int:
    """The oversampling factor to use: the one asked for, raised to respect the uniqueness bound if needed."""
    if oversample < 1 or int(oversample) != oversample:
        raise ValueError(f"oversample must be a whole number >= 1, got {oversample}")
    need = physics.min_oversample(scene.fb_max, scene.a, scene.sample_rate, scene.f0_max)
    if need > MAX_OVERSAMPLE:
        raise SceneError(f"fb={scene.fb_max:g} with a={scene.a:g} needs the FDM oversampled x{need} at "
                         f"{scene.sample_rate} Hz (uniqueness bound k < e/(fb sqrt(2a))); the limit is "
                         f"x{MAX_OVERSAMPLE}: lower fb or a")
    if need > oversample:
        if warn:
            if physics.min_oversample(scene.fb_max, scene.a, scene.sample_rate) == need:
                why = (f"fb={scene.fb_max:g} at {scene.sample_rate} Hz breaks the FDM uniqueness bound "
                       f"k < e/(fb sqrt(2a))")
            else:
                why = f"f0={scene.f0_max:g} Hz at {scene.sample_rate} Hz breaks the FDM stability bound k < 2/w"
            warnings.warn(f"{why}; oversampling raised from {oversample} to {need}", OversampleWarning, stacklevel=3)
        return need
    return int(oversample)


def render_fdm(scene: Scene, oversample: int = 1) -> Render:
    """Render a scene with the FDM at `oversample` times its sample rate, returned at its sample rate. Bow curves
    are followed at every step of the scheme, and so is a pitch curve (w(t) = 2 pi f0(t); q = w(t) u)."""
    os_ = check_oversample(scene, oversample)
    t0 = time.perf_counter()
    u, eta = _run(scene, os_, os_, scene.n_samples)
    secs = time.perf_counter() - t0
    t = np.arange(scene.n_samples) / scene.sample_rate
    q = (2.0 * math.pi * scene.f0_at(t) if scene.pitch_varies else scene.omega) * u
    q[0] = scene.q0  # exact by construction; avoid the w * (q0 / w) rounding
    vb = scene.vb_at(t)
    return Render(scene, t, q, eta + vb, method=Played("fdm", os_),
                  seconds=secs, info=RenderInfo(oversample=os_))


def fdm_steps_p(scene: Scene, oversample: int) -> np.ndarray:
    """p at every step of the scheme `render_fdm(scene, oversample)` runs (its render's p is this [::oversample]):
    a reference finer than the audio rate, for a cycle's phase between samples (metrics.cycle_shape_error). 16 bytes
    a step: 2 GB for 30 s at x100 (v_B is added in place, a chunk at a time, so that nothing more is held)."""
    os_ = check_oversample(scene, oversample)
    n = os_ * (scene.n_samples - 1) + 1
    _, eta = _run(scene, os_, 1, n)
    for a in range(0, n, CHUNK_STEPS):
        eta[a:a + CHUNK_STEPS] += scene.vb_at(np.arange(a, min(a + CHUNK_STEPS, n)) / (scene.sample_rate * os_))
    return eta


def _run(scene: Scene, os_: int, stride: int, n_out: int):
    """(u, eta) every `stride` steps of the scheme at os_ times the scene's rate, from its start state."""
    from ..controls import Curve

    w = Curve(tuple((t, 2.0 * math.pi * f) for t, f in scene.f0.points)) if scene.pitch_varies else scene.omega
    w0 = float(scene.f0_at(0.0)) * 2.0 * math.pi if scene.pitch_varies else w
    k = 1.0 / (scene.sample_rate * os_)
    u0 = scene.q0 / w0
    fb0, vb0 = float(scene.fb_at(0.0)), float(scene.vb_at(0.0))
    u_prev = taylor_start(u0, scene.p0, k, w0, fb0, vb0, scene.a)
    return run_fdm_raw(u_prev, u0, n_out, stride, k, w, scene.fb, scene.vb, scene.a, eta0=scene.p0 - vb0)


def fdm_batch(q0, p0, n_out, stride, k, w, fb, vb, a, on_progress=None, loop: str = "core"):
    """The FDM over many initial states at once, same start and iteration as `render_fdm`.

    q0, p0: arrays (B,); w, fb: numbers or arrays (B,) (states at several pitches and bows roll together); vb: a
    number, an array (B,), or a function of the time t = n k of step n returning (B,) values (a bow that changes:
    the releases of a score's notes). Steps of size k; returns q, p of shape (B, n_out) at every `stride`-th step
    (column 0 is the initial state). on_progress(fraction) is called as the work goes.

    loop "core": each state by the compiled loop (run_fdm_raw), the states spread over the CPU's cores (the loop
    lets go of the GIL), where vb is not a function of time; "numpy" (and a vb that is one): vectorised across the
    states, the readable reference. Both agree to the bit. Training data is this batch: a shipped recipe's took
    19-64 s in numpy and takes 5-17 s in the core (benchmarks/train_data.py)."""
    q0 = np.asarray(q0, dtype=float)
    p0 = np.asarray(p0, dtype=float)
    moving = callable(vb)
    if moving:
        vb_fn = vb
        vb_at = lambda t: np.broadcast_to(np.asarray(vb_fn(t), dtype=float), q0.shape)  # noqa: E731
    else:
        fixed = np.broadcast_to(np.asarray(vb, dtype=float), q0.shape)
        vb_at = lambda t: fixed  # noqa: E731
    fb = np.broadcast_to(np.asarray(fb, dtype=float), q0.shape)
    w = np.broadcast_to(np.asarray(w, dtype=float), q0.shape)
    if q0.size and k >= physics.max_stable_step(float(fb.max()), a):
        raise ValueError(f"step k={k:g} s breaks the uniqueness bound for fb={float(fb.max()):g}, a={a:g}")
    vb = vb_at(0.0)
    u_cur = q0 / w
    u_prev = taylor_start(u_cur, p0, k, w, fb, vb, a)
    eta = p0 - vb
    if loop == "core" and not moving:
        q, p = _fdm_rows(u_prev, u_cur, eta, n_out, stride, k, w, fb, vb, a, on_progress)
        q[:, 0] = q0
        return q, p
    c, ck, w2 = 2.0 / k, 2.0 / (k * k), w * w
    q = np.empty((q0.size, n_out))
    p = np.empty((q0.size, n_out))
    for j in range(n_out):
        for s in range(stride):
            vb = vb_at((j * stride + s) * k)
            b = c * vb + ck * (u_prev - u_cur) + w2 * u_cur
            eta = _solve_eta_vec(eta, b, c, fb, a)
            if s == 0:
                q[:, j] = w * u_cur
                p[:, j] = eta + vb
            u_prev, u_cur = u_cur, u_prev + 2.0 * k * (eta + vb)
        if on_progress is not None:
            on_progress((j + 1) / n_out)
    q[:, 0] = q0
    return q, p


def _fdm_rows(u_prev, u_cur, eta, n_out, stride, k, w, fb, vb, a, on_progress=None):
    """fdm_batch's states one by one in the compiled loop, in slices over threads (the core runs without the GIL;
    compiled.share: a Ctrl-C stops them within a slice); each row's arithmetic is the numpy batch's, so the rows are
    the same to the bit."""
    from .. import compiled

    n = u_cur.size
    q, p = np.empty((n, n_out)), np.empty((n, n_out))
    per = max(1, min(64, n // 32))

    def rows(lo: int) -> None:
        for i in range(lo, min(lo + per, n)):
            u, e = run_fdm_raw(u_prev[i], u_cur[i], n_out, stride, k, w[i], fb[i], vb[i], a, eta0=eta[i])
            q[i] = w[i] * u
            p[i] = e + vb[i]

    report = None if on_progress is None else lambda done: on_progress(min(1.0, done * per / n))
    compiled.share(rows, range(0, n, per), min(4, compiled.usable_cores()), on_item=report)
    return q, p


def _solve_eta_vec(guess, b, c, fb, a):
    if guess.size <= DENSE_BELOW:
        return _solve_eta_dense(guess, b, c, fb, a)
    return _solve_eta_bracketed(guess, b, c, fb, a)


def _solve_eta_bracketed(guess, b, c, fb, a):
    lo = (-b - fb) / c
    hi = (-b + fb) / c
    x = np.clip(guess, lo, hi)
    active = np.ones(x.shape, dtype=bool)
    for _ in range(physics.NEWTON_MAXIT):
        xa, la, ha, ba, fa = x[active], lo[active], hi[active], b[active], fb[active]
        fx = c * xa + fa * physics.phi(xa, a) + ba
        pos = fx > 0.0
        ha = np.where(pos, xa, ha)
        la = np.where(pos, la, xa)
        d = c + fa * physics.dphi(xa, a)
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = np.where(d > 0.0, xa - fx / d, 0.5 * (la + ha))
        bad = ~((la <= xn) & (xn <= ha))
        xn = np.where(bad, 0.5 * (la + ha), xn)
        done = np.abs(xn - xa) <= physics.NEWTON_TOL
        x[active], lo[active], hi[active] = xn, la, ha
        idx = np.flatnonzero(active)
        active[idx[done]] = False
        if not active.any():
            break
    return x


def _solve_eta_dense(guess, b, c, fb, a):
    """`_solve_eta_bracketed` for a few states (a score's releases), where numpy's per-call overhead, not the
    arithmetic, is the cost: every state iterates until the slowest is done (a converged one held by np.where)
    instead of gathering the active states each step. The same Newton steps in the same bracket, phi and dphi
    written as in `physics` with their exponential shared, so each state's result is the bracketed iteration's to
    the bit: a stick-slip release amplifies a last-bit difference to 1e-5 within 0.1 s."""
    lo = (-b - fb) / c
    hi = (-b + fb) / c
    x = np.clip(guess, lo, hi)
    s2a = math.sqrt(2.0 * a)
    done = np.zeros(x.shape, dtype=bool)
    for _ in range(physics.NEWTON_MAXIT):
        ax = -a * x
        e = np.exp(ax * x + 0.5)
        fx = c * x + fb * (s2a * x * e) + b
        pos = fx > 0.0
        hi = np.where(pos, x, hi)
        lo = np.where(pos, lo, x)
        d = c + fb * (s2a * e * (1.0 + 2.0 * ax * x))
        mid = 0.5 * (lo + hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = np.where(d > 0.0, x - fx / d, mid)
        xn = np.where(done | ~((lo <= xn) & (xn <= hi)), np.where(done, x, mid), xn)
        done |= np.abs(xn - x) <= physics.NEWTON_TOL
        x = xn
        if done.all():
            break
    return x
