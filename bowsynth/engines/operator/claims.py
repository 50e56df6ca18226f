"""A model file's claims (its box of bows, its range of states) held to the scalings its weights were trained with:
a file whose box or state range was widened, its digest recomputed, claims what its network never saw."""

from __future__ import annotations

import math

import numpy as np

from .npnet import PARAM_SPAN, NetConfig, param_inputs, state_scaling

# A range model's network takes its bow as (log F_B / w, v_B) scaled so that the box it was trained over spans
# +-PARAM_SPAN (pcenter, pscale), and every model its state scaled by the centre and half-range of the states it was
# trained on (center, halfrange; for a bow-scaled model affine in the bow). Measured on the shipped catalogue: every
# box lies inside its scaling's (a refinement keeps its parent's scaling and a box inside the parent's), every state
# range within 3.7 % of the half-range of its scaling's (a refinement whose states reach a little past its parent's).
STATE_MARGIN = 0.25  # of the half-range: a claimed state range may reach this far past its scaling's
BOX_SLACK = 1e-5  # in the scaled inputs: float32 rounding of the box's edges


def _span(lo: float, hi: float, log: bool) -> str:
    return f"{math.exp(lo):.4g}-{math.exp(hi):.4g}" if log else f"{lo:.4g}-{hi:.4g}"


def claims_error(domain, cfg: NetConfig, w: dict) -> str | None:
    """Why the domain's box or state range claims more than the weights' scalings were fitted to, or None."""
    pin = np.zeros((1, cfg.params))
    if domain.box is not None and cfg.params:
        b = domain.box
        corners = [[max(beta, 1e-12), vb] for beta in b[:2] for vb in b[2:]]
        u = np.array([[math.log(max(beta, 1e-12)), vb] for beta, vb in corners])
        x = (u - w["pcenter"].astype(float)) / w["pscale"].astype(float)
        lo = w["pcenter"].astype(float) - PARAM_SPAN * w["pscale"].astype(float)
        hi = w["pcenter"].astype(float) + PARAM_SPAN * w["pscale"].astype(float)
        # a box from F_B / w 0 has no logarithm: its bottom is not compared
        over = (x[:, 1].min() < -PARAM_SPAN - BOX_SLACK or x[:, 1].max() > PARAM_SPAN + BOX_SLACK
                or x[:, 0].max() > PARAM_SPAN + BOX_SLACK or (b[0] > 0 and x[:, 0].min() < -PARAM_SPAN - BOX_SLACK))
        if over:
            return (f"its box (F_B / w {b[0]:.4g}-{b[1]:.4g}, v_B {b[2]:.4g}-{b[3]:.4g}) reaches past the bows its "
                    f"network was trained over (F_B / w {_span(lo[0], hi[0], True)}, v_B {_span(lo[1], hi[1], False)})")
        pin = param_inputs(w, corners)
    c, h = state_scaling(w, cfg, pin)
    lo, hi = (c - (1 + STATE_MARGIN) * h).min(axis=0), (c + (1 + STATE_MARGIN) * h).max(axis=0)
    claimed = ((domain.q_lo, domain.q_hi), (domain.p_lo, domain.p_hi))
    for i, name in enumerate(("q", "p")):
        if claimed[i][0] < lo[i] or claimed[i][1] > hi[i]:
            return (f"its range of {name} ({claimed[i][0]:.4g} to {claimed[i][1]:.4g}) reaches past the states its "
                    f"network was trained on ({(c - h).min(axis=0)[i]:.4g} to {(c + h).max(axis=0)[i]:.4g})")
    return None
