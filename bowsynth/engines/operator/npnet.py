"""The network without torch: its configuration, the weight names and shapes a model file must hold, and the
modified MLP's forward pass in numpy (float64, from the float32 weights).

Rendering reads a model file and evaluates it here, so a render never imports torch (2-8 s on this machine);
`network.DeepONet` is the same network in torch, built only for training (tests/test_operator.py checks that the two
agree).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ... import physics


@dataclass
class NetConfig:
    width: int = 64
    depth: int = 4
    k: int = 64  # features per state variable; branch and trunk emit 2k each
    ff_branch: int = 32  # random Fourier features (pairs) on the branch input
    ff_trunk: int = 32
    sigma_branch: float = 1.0
    sigma_trunk: float = 2.0
    linear_flow: bool = True  # carry the exact frictionless flow R(tau) x0 in the output (False: x0, for ablation)
    # Range models: the branch also takes the window's bow (log beta, v_B), scaled by the buffers pcenter/pscale so
    # that the box spans [-PARAM_SPAN, PARAM_SPAN] before the Fourier features (0 inputs: a point model)
    params: int = 0
    # the correction scaled by beta / beta_ref (range models): what friction adds over a window is first order in
    # beta, so the net's output stays O(1) across a box whose beta spans a factor 27
    corr_beta: bool = False
    # point models whose note starts slowly: the linear part is the exact flow of the bowed mass linearised at its
    # rest state (physics.flow_coefficients with the buffer lin = (d, q_s)), not the frictionless rotation, so that
    # the onset's growth rate is exact and the net learns only the nonlinear remainder of the friction
    rest_linear: bool = False
    # range models whose playing amplitude changes with the bow (stick-slip: the limit cycle's size grows with
    # F_B / w, 0.6 to 2.1 across its box): the state is scaled per bow, its centre and log half-range affine in the
    # bow inputs (buffers center_slope, halfrange_slope, fitted to the training renders), so that every bow's limit
    # cycle fills the branch's input as a point model's does
    bow_scaled: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


# Parameter inputs normalised to [-1, 1] like the state made rollouts diverge (median NMSE(p) 32 over a 4 x 4 grid);
# scaled to [-0.3, 0.3] the branch is smoother in the bow: median 0.15 after the same 15 minutes of training
PARAM_SPAN = 0.3


def linear_part(cfg: NetConfig, tau, lin=None) -> tuple:
    """(m11, m12, m21, m22, k_q, k_p) at times tau: the network's exact linear part x = M x0 + k. The free
    oscillator's rotation, or with lin = (d, q_s) the flow linearised at rest (physics.flow_coefficients); the
    identity for ablation models without the linear flow (their output carries x0)."""
    if cfg.linear_flow:
        return physics.flow_coefficients(tau, lin)
    one, zero = np.ones_like(np.asarray(tau, float)), np.zeros_like(np.asarray(tau, float))
    return one, zero, zero, one, zero, zero


def weight_shapes(cfg: NetConfig) -> dict[str, tuple]:
    """Name -> shape of every tensor of a DeepONet with this configuration (torch's state_dict layout)."""
    out: dict[str, tuple] = {"bias": (2,), "center": (2,), "halfrange": (2,), "corr_scale": (2,), "window": ()}
    if cfg.params:
        out.update({"pcenter": (cfg.params,), "pscale": (cfg.params,)})
    if cfg.rest_linear:
        out["lin"] = (2,)
    if cfg.bow_scaled:
        out.update({"center_slope": (2, cfg.params), "halfrange_slope": (2, cfg.params)})
    for part, in_dim, m in (("branch", 2 + cfg.params, cfg.ff_branch), ("trunk", 1, cfg.ff_trunk)):
        out[f"{part}.ff.B"] = (in_dim, m)
        for gate in ("U", "V"):
            out[f"{part}.{gate}.weight"] = (cfg.width, 2 * m)
            out[f"{part}.{gate}.bias"] = (cfg.width,)
        for i in range(cfg.depth):
            out[f"{part}.hidden.{i}.weight"] = (cfg.width, 2 * m if i == 0 else cfg.width)
            out[f"{part}.hidden.{i}.bias"] = (cfg.width,)
        out[f"{part}.out.weight"] = (2 * cfg.k, cfg.width)
        out[f"{part}.out.bias"] = (2 * cfg.k,)
    return out


def modified_mlp(w: dict, part: str, depth: int, x: np.ndarray) -> np.ndarray:
    """network.ModifiedMLP.forward in float64: Fourier features, gates U and V mixed into every hidden layer."""
    f = lambda name: np.asarray(w[f"{part}.{name}"], dtype=np.float64)  # noqa: E731
    z = 2 * math.pi * np.asarray(x, dtype=np.float64) @ f("ff.B")
    h = np.concatenate([np.cos(z), np.sin(z)], axis=-1)
    u = np.tanh(h @ f("U.weight").T + f("U.bias"))
    v = np.tanh(h @ f("V.weight").T + f("V.bias"))
    for i in range(depth):
        z = np.tanh(h @ f(f"hidden.{i}.weight").T + f(f"hidden.{i}.bias"))
        h = z * u + (1 - z) * v
    return h @ f("out.weight").T + f("out.bias")


def trunk_features(w: dict, cfg: NetConfig, s: np.ndarray) -> np.ndarray:
    """DeepONet.trunk_features: (M,) window fractions -> (M, 2, k)."""
    return modified_mlp(w, "trunk", cfg.depth, np.asarray(s, float)[:, None]).reshape(-1, 2, cfg.k) / math.sqrt(cfg.k)


def param_inputs(w: dict, par) -> np.ndarray:
    """(B, 2) bows (beta, v_B) -> the branch's parameter inputs (B, 2): (log beta, v_B) scaled by pcenter, pscale."""
    par = np.asarray(par, float).reshape(-1, 2)
    u = np.stack([np.log(np.maximum(par[:, 0], 1e-12)), par[:, 1]], axis=1)
    x = (u - w["pcenter"].astype(float)) / w["pscale"].astype(float)
    # below the box's bottom in beta the input is held there (Domain.plays_below: first order in beta, via gain)
    x[:, 0] = np.maximum(x[:, 0], -PARAM_SPAN)
    return x


def gain(w: dict, cfg: NetConfig, beta) -> np.ndarray:
    """The correction's factor beta / beta_ref (1 unless cfg.corr_beta); beta_ref is the box's centre."""
    beta = np.asarray(beta, float)
    if not cfg.corr_beta:
        return np.ones_like(beta)
    return beta / math.exp(float(w["pcenter"][0]))


def state_scaling(w: dict, cfg: NetConfig, pin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state's centre and half-range (N, 2) for bows with branch inputs pin (N, n_par) (param_inputs): the
    buffers center, halfrange, and for a bow-scaled model center + pin C^T and halfrange exp(pin H^T)."""
    pin = np.asarray(pin, float).reshape(len(pin), -1)
    c, h = w["center"].astype(float), w["halfrange"].astype(float)
    if not cfg.bow_scaled:
        return np.broadcast_to(c, (len(pin), 2)), np.broadcast_to(h, (len(pin), 2))
    return (c + pin @ w["center_slope"].astype(float).T,
            h * np.exp(pin @ w["halfrange_slope"].astype(float).T))


def branch_features(w: dict, cfg: NetConfig, x0: np.ndarray, par=None) -> np.ndarray:
    """DeepONet.branch_features: (B, 2) states (and (B, 2) bows for a range model) -> (B, 2, k)."""
    x0 = np.asarray(x0, float).reshape(-1, 2)
    pin = param_inputs(w, par) if cfg.params else np.zeros((len(x0), 0))
    c, h = state_scaling(w, cfg, pin)
    x = (x0 - c) / h
    if cfg.params:
        x = np.concatenate([x, pin], axis=1)
    return modified_mlp(w, "branch", cfg.depth, x).reshape(-1, 2, cfg.k)
