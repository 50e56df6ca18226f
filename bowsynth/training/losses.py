"""The loss terms, by name (each normalised to O(1) by the correction scale c), and the one weighted sum:

  data  - trajectories against a high-rate batch FDM from band states (hybrid only)
  end   - the window's end state against the FDM (it seeds the next window, so its error compounds)
  kin   - kinematic residual q' - p
  fric  - friction residual p' + q + beta phi(p - v_B); stiff at high force, where it fights the data
  deriv - the network's d x / d tau on the data trajectories against the ODE's right-hand side at the *true* states:
          an exact target (unlike fric, evaluated at predicted states) that weights harmonic k by k, so the small,
          fast part of the correction (the upper harmonics a value loss barely sees) is learned
  roll  - chains of K windows, each started from the network's own end state, against the FDM's window boundaries:
          what a held note's pitch is made of (the windows' small phase errors added up), which one window hides
"""

from __future__ import annotations

import torch

from .. import physics
from ..engines.operator.network import DeepONet
from ..scene import Scene

STIFF = physics.STIFF  # the friction residual is dropped from the hybrid loss by default above it
FRIC_WEIGHT = 0.03  # hybrid, non-stiff: fb 100, 3 min SOAP: 0.3 -> 2.3e-3, 0.1 -> 3.8e-4, 0.03 -> 3.5e-5 NMSE(p) 1 s
# range models: soft box, 10 min, 16 held-out bows, harmonics 1-10 median / worst: without it 11.4 / 16.2 dB, at weight
# 1: 0.79 / 1.76, at 0.1: 0.70 / 1.30 (docs/BENCHMARKS.md, "The whole instrument")
DERIV_WEIGHT = 0.1


def stiffness(scene: Scene, beta: float | None = None) -> float:
    """Friction slope at rest in dimensionless time: beta sqrt(2a) e^{1/2} (beta: the scene's, or a range's top)."""
    return physics.stiffness(scene.beta if beta is None else beta, scene.a)


def default_weights(scene: Scene, hybrid: bool, beta_max: float | None = None, deriv: float | None = None,
                    rollout: float = 0.0) -> dict:
    """The loss weights. beta_max: a range model's top F_B / w. A range model drops the friction residual: trained
    with it (0.03) over the soft box for 40 min, its weighted term ended 20x the data term and the validation's median
    NMSE(p) was 0.080; without it, 30 min, 0.019 (docs/BENCHMARKS.md, range models). deriv: the derivative term's
    weight (None: DERIV_WEIGHT for a range model, none for a point model; 0: none); rollout: the chains' (0: none)."""
    if not hybrid:
        return {"kin": 1.0, "fric": 1.0}
    w = {"data": 1.0, "end": 1.0, "kin": 1.0}
    if beta_max is None and stiffness(scene) < STIFF:
        w["fric"] = FRIC_WEIGHT
    if deriv is None:
        deriv = DERIV_WEIGHT if beta_max is not None else 0.0
    if deriv > 0:
        w["deriv"] = float(deriv)
    if rollout > 0:
        w["roll"] = float(rollout)
    return w


def weighted(terms: dict, weights: dict):
    """The training loss: the weighted sum of the named terms."""
    return sum(weights[k] * v for k, v in terms.items())


def residuals(net: DeepONet, x, dx, b, vb, a: float, gain=None):
    """Dimensionless ODE residuals (kinematic, friction) of trajectories x (B, M, 2) with derivatives dx, scaled by
    c / T (times a range model's gain (B,)). b, vb: floats, or (B, 1) tensors of each trajectory's bow."""
    q, p = x[..., 0], x[..., 1]
    dq_ref, dp_ref = physics.rhs_tau(q, p, b, vb, a)
    scale = net.corr_scale / net.window
    g = 1.0 if gain is None else gain[:, None]
    return (dx[..., 0] - dq_ref) / (scale[0] * g), (dx[..., 1] - dp_ref) / (scale[1] * g)


def loss_terms(net, batch: dict, scene: Scene, weights: dict) -> dict:
    """The named loss terms. Branch and trunk run once each on the data and physics points together: on a CPU
    these small networks cost mostly per-call overhead. A range model's batch carries each state's bow (beta, v_B)
    in data_par and phys_par."""
    use_data = "data" in weights or "end" in weights or "deriv" in weights
    use_phys = "kin" in weights or "fric" in weights
    ranged = "phys_par" in batch
    x0s = [batch["data_x0"]] * use_data + [batch["phys_x0"]] * use_phys
    taus = [batch["data_tau"]] * use_data + [batch["phys_tau"]] * use_phys
    par = torch.cat([batch["data_par"]] * use_data + [batch["phys_par"]] * use_phys) if ranged else None
    gain = net.gain(par) if ranged else None
    bf = net.branch_features(torch.cat(x0s), par)
    tau_all = torch.cat(taus)
    if use_phys or "deriv" in weights:
        tf, dtf = net.trunk_features_jvp(tau_all / net.window)
    else:
        tf, dtf = net.trunk_features(tau_all / net.window), None
    terms = {}
    nb, nm = (len(batch["data_x0"]), len(batch["data_tau"])) if use_data else (0, 0)
    if use_data:
        g = None if gain is None else gain[:nb]
        if "deriv" in weights:
            pred, dpred = net.assemble(batch["data_x0"], batch["data_tau"], bf[:nb], tf[:nm], dtf[:nm], gain=g)
            b, vb = _bows(batch, "data_par", scene)
            rq, rp = residuals(net, batch["data_x"], dpred, b, vb, scene.a, gain=g)
            terms["deriv"] = (rq.square().mean() + rp.square().mean()) / 2
        else:
            pred = net.assemble(batch["data_x0"], batch["data_tau"], bf[:nb], tf[:nm], gain=g)
        err = (pred - batch["data_x"]) / (net.corr_scale if g is None else net.corr_scale * g[:, None, None])
        if "data" in weights:
            terms["data"] = err.square().mean()
        if "end" in weights:
            terms["end"] = err[:, -1].square().mean()
    if use_phys:
        g = None if gain is None else gain[nb:]
        x, dx = net.assemble(batch["phys_x0"], batch["phys_tau"], bf[nb:], tf[nm:], dtf[nm:], gain=g)
        b, vb = _bows(batch, "phys_par", scene)
        rk, rf = residuals(net, x, dx, b, vb, scene.a, gain=g)
        if "kin" in weights:
            terms["kin"] = rk.square().mean()
        if "fric" in weights:
            terms["fric"] = rf.square().mean()
    if "roll" in weights:
        terms["roll"] = rollout_term(net, batch)
    return terms


def rollout_term(net, batch: dict):
    """The mean square error, in units of the correction scale, of K windows rolled out as a render does (each from
    the previous window's predicted end), at every window boundary of the batch's chains."""
    chain = batch["chain_x"]
    par = batch.get("chain_par")
    gain = None if par is None else net.gain(par)
    scale = net.corr_scale if gain is None else net.corr_scale * gain[:, None]
    end = batch["data_tau"][-1:]  # the window
    x, total = chain[:, 0], 0.0
    for k in range(1, chain.shape[1]):
        x = net(x, end, par)[:, -1]
        total = total + ((x - chain[:, k]) / scale).square().mean()
    return total / (chain.shape[1] - 1)


def _bows(batch: dict, key: str, scene: Scene):
    """Each trajectory's bow, (B, 1) tensors for a range model's batch, else the scene's (floats)."""
    if key in batch:
        return batch[key][:, 0:1], batch[key][:, 1:2]
    return scene.beta, scene.vb
