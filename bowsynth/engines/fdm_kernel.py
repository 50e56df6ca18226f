"""The FDM step in numba, for the live engine's block loop (`operator.voices`), which switches a voice from the
operator to the FDM mid-block; renders run the compiled core's step (src/core/fdm.cpp, through `fdm.run_fdm_raw`).
Same scheme, start and Newton iteration (documented in `fdm`), w(t) linear between its breakpoints."""

from __future__ import annotations

import numba
import numpy as np
from numba.extending import overload

from .. import physics


@overload(physics._exp)
def _exp_numba(x):  # lets numba compile physics.phi / dphi unchanged
    return lambda x: np.exp(x)


_phi = numba.njit(physics.phi, inline="always")
_dphi = numba.njit(physics.dphi, inline="always")


@numba.njit(cache=True)
def _solve_eta(guess, b, c, fb, a):
    """Root of c*x + fb*phi(x) + b (increasing in x under the uniqueness bound), Newton kept inside a bracket."""
    lo = (-b - fb) / c
    hi = (-b + fb) / c
    x = min(max(guess, lo), hi)
    for _ in range(physics.NEWTON_MAXIT):
        fx = c * x + fb * _phi(x, a) + b
        if fx > 0.0:
            hi = x
        else:
            lo = x
        d = c + fb * _dphi(x, a)
        xn = x - fx / d if d > 0.0 else 0.5 * (lo + hi)
        if not (lo <= xn <= hi):
            xn = 0.5 * (lo + hi)
        if abs(xn - x) <= physics.NEWTON_TOL:
            return xn
        x = xn
    return x


@numba.njit(cache=True, inline="always")
def _control(ts, vs, t, i):
    """Piecewise-linear control at time t, held outside its breakpoints; i is the segment of the previous call
    (times only grow, so the search is amortised O(1))."""
    n = ts.shape[0]
    while i + 1 < n and ts[i + 1] <= t:
        i += 1
    if t <= ts[0] or i + 1 >= n:
        return vs[0] if t <= ts[0] else vs[n - 1], i
    return vs[i] + (vs[i + 1] - vs[i]) * (t - ts[i]) / (ts[i + 1] - ts[i]), i


@numba.njit(cache=True)
def kernel(u_prev, u_cur, eta, n0, n_out, stride, k, w_t, w_v, fb_t, fb_v, vb_t, vb_v, a, u_out, eta_out):
    """The angular frequency w, bow force and speed follow their breakpoints (w_t, w_v), (fb_t, fb_v), (vb_t, vb_v)
    step by step, at t = n k (a pitch curve: u_tt + w(t)^2 u = -F_B phi); this call runs steps n0, n0 + 1, ..."""
    c = 2.0 / k
    ck = 2.0 / (k * k)
    ifb = 0
    ivb = 0
    iw = 0
    for j in range(n_out):
        for s in range(stride):
            t = (n0 + j * stride + s) * k
            fb, ifb = _control(fb_t, fb_v, t, ifb)
            vb, ivb = _control(vb_t, vb_v, t, ivb)
            w, iw = _control(w_t, w_v, t, iw)
            b = c * vb + ck * (u_prev - u_cur) + w * w * u_cur
            eta = _solve_eta(eta, b, c, fb, a)
            if s == 0:
                u_out[j] = u_cur
                eta_out[j] = eta
            u_next = u_prev + 2.0 * k * (eta + vb)
            u_prev = u_cur
            u_cur = u_next
    return u_prev, u_cur, eta
