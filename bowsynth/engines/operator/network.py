"""The PI-DeepONet: branch on the window's initial state, trunk on time in the window, cartesian-product form.

    x(tau) = R(tau) x0 + s * c * N(x0, s),   s = tau / T,   N_j = <branch_j(x0), trunk_j(s)> + bias_j

R(tau) is the exact flow of the frictionless oscillator (a rotation), so the network learns only what friction
adds; the factor s makes x(0) = x0 exact (hard initial condition). c scales the correction to O(1).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ... import physics
from .npnet import PARAM_SPAN, NetConfig, linear_part  # noqa: F401  (torch-free: model files are read without torch)


class FourierFeatures(nn.Module):
    def __init__(self, in_dim: int, m: int, sigma: float, gen: torch.Generator):
        super().__init__()
        self.register_buffer("B", torch.randn(in_dim, m, generator=gen) * sigma)

    def forward(self, x):
        z = 2 * math.pi * x @ self.B
        return torch.cat([torch.cos(z), torch.sin(z)], dim=-1)


class ModifiedMLP(nn.Module):
    """Wang et al. (2021): two gates U, V computed from the input mix into every hidden layer."""

    def __init__(self, in_dim: int, width: int, depth: int, out_dim: int, m: int, sigma: float, gen):
        super().__init__()
        self.ff = FourierFeatures(in_dim, m, sigma, gen)
        self.U = nn.Linear(2 * m, width)
        self.V = nn.Linear(2 * m, width)
        self.hidden = nn.ModuleList([nn.Linear(2 * m if i == 0 else width, width) for i in range(depth)])
        self.out = nn.Linear(width, out_dim)

    def forward(self, x):
        h = self.ff(x)
        u, v = torch.tanh(self.U(h)), torch.tanh(self.V(h))
        for layer in self.hidden:
            z = torch.tanh(layer(h))
            h = z * u + (1 - z) * v
        return self.out(h)


class DeepONet(nn.Module):
    """Scales live in buffers, so a saved model carries everything needed to evaluate it."""

    def __init__(self, cfg: NetConfig, seed: int = 0):
        super().__init__()
        gen = torch.Generator().manual_seed(seed)
        torch.manual_seed(seed)
        self.cfg = cfg
        self.branch = ModifiedMLP(2 + cfg.params, cfg.width, cfg.depth, 2 * cfg.k, cfg.ff_branch, cfg.sigma_branch, gen)
        self.trunk = ModifiedMLP(1, cfg.width, cfg.depth, 2 * cfg.k, cfg.ff_trunk, cfg.sigma_trunk, gen)
        self.bias = nn.Parameter(torch.zeros(2))
        self.register_buffer("center", torch.zeros(2))  # state centre and half-range: branch input scaling
        self.register_buffer("halfrange", torch.ones(2))
        self.register_buffer("corr_scale", torch.ones(2))  # c: size of the friction correction per variable
        self.register_buffer("window", torch.tensor(2 * math.pi))  # T, in tau
        if cfg.params:  # range models: (log beta, v_B) -> (u - pcenter) / pscale, the box within +-PARAM_SPAN
            self.register_buffer("pcenter", torch.zeros(cfg.params))
            self.register_buffer("pscale", torch.ones(cfg.params))
        if cfg.bow_scaled:
            if not cfg.params:
                raise ValueError("bow_scaled is for range models")
            self.register_buffer("center_slope", torch.zeros(2, cfg.params))  # npnet.state_scaling
            self.register_buffer("halfrange_slope", torch.zeros(2, cfg.params))
        if cfg.rest_linear:
            if cfg.params or not cfg.linear_flow:
                raise ValueError("rest_linear is for point models with the linear flow")
            self.register_buffer("lin", torch.zeros(2, dtype=torch.float64))  # (d, q_s): physics.rest_linearisation

    def set_scales(self, center, halfrange, corr_scale, window: float):
        self.center.copy_(torch.as_tensor(center))
        self.halfrange.copy_(torch.as_tensor(halfrange))
        self.corr_scale.copy_(torch.as_tensor(corr_scale))
        self.window.fill_(float(window))

    def set_rest_linear(self, beta: float, vb: float, a: float):
        self.lin.copy_(torch.tensor(physics.rest_linearisation(beta, vb, a), dtype=torch.float64))

    def flow(self, x0, tau):
        """The linear part (B, M, 2) and its tau-derivative: R(tau) x0, the flow linearised at rest, or x0."""
        q0, p0 = x0[:, 0:1], x0[:, 1:2]
        lin = (float(self.lin[0]), float(self.lin[1])) if self.cfg.rest_linear else None
        m11, m12, m21, m22, kq, kp = (torch.as_tensor(c, dtype=x0.dtype, device=x0.device)[None, :]
                                      for c in linear_part(self.cfg, tau.detach().cpu().double().numpy(), lin))
        lq, lp = m11 * q0 + m12 * p0 + kq, m21 * q0 + m22 * p0 + kp
        if not self.cfg.linear_flow:
            return torch.stack([lq, lp], dim=-1), torch.zeros(*lq.shape, 2, dtype=x0.dtype)
        d, qs = lin if lin is not None else (0.0, 0.0)
        return torch.stack([lq, lp], dim=-1), torch.stack([lp, -(lq - qs) - d * lp], dim=-1)

    def set_box(self, box):
        """Scale the parameter inputs to a ParamBox (log beta, v_B): its edges at +-PARAM_SPAN (a side of zero
        width gives input 0)."""
        lo = torch.tensor([math.log(max(box.beta_lo, 1e-12)), box.vb_lo], dtype=torch.float64)
        hi = torch.tensor([math.log(max(box.beta_hi, 1e-12)), box.vb_hi], dtype=torch.float64)
        half = (hi - lo) / 2
        self.pcenter.copy_((lo + hi) / 2)
        self.pscale.copy_(torch.where(half > 0, half / PARAM_SPAN, torch.ones_like(half)))

    def param_inputs(self, par):
        """(B, 2) bows (beta, v_B) -> (B, 2) branch inputs (npnet.param_inputs)."""
        u = torch.stack([par[:, 0].clamp_min(1e-12).log(), par[:, 1]], dim=1)
        return (u - self.pcenter) / self.pscale

    def gain(self, par):
        """(B,) correction factors beta / beta_ref, or None (npnet.gain)."""
        if not self.cfg.corr_beta:
            return None
        return par[:, 0] / self.pcenter[0].exp()

    def set_bow_scaling(self, center, halfrange, center_slope, halfrange_slope):
        """A bow-scaled range model's state scaling (npnet.state_scaling): at the box's centre, and the slopes of the
        centre and of the log half-range in the branch's bow inputs, (2, n_par) each."""
        self.center.copy_(torch.as_tensor(center))
        self.halfrange.copy_(torch.as_tensor(halfrange))
        self.center_slope.copy_(torch.as_tensor(center_slope))
        self.halfrange_slope.copy_(torch.as_tensor(halfrange_slope))

    def branch_features(self, x0, par=None):
        """(B, 2) states (and (B, 2) bows (beta, v_B) for a range model) -> (B, 2, k)."""
        if not self.cfg.params:
            return self.branch((x0 - self.center) / self.halfrange).view(-1, 2, self.cfg.k)
        pin = self.param_inputs(par).to(x0.dtype)
        if self.cfg.bow_scaled:
            scale = self.halfrange * torch.exp(pin @ self.halfrange_slope.T)
            x = (x0 - self.center - pin @ self.center_slope.T) / scale
        else:
            x = (x0 - self.center) / self.halfrange
        return self.branch(torch.cat([x, pin], dim=1)).view(-1, 2, self.cfg.k)

    def trunk_features(self, s):
        """(M,) window fractions -> (M, 2, k)."""
        return self.trunk(s[:, None]).view(-1, 2, self.cfg.k) / math.sqrt(self.cfg.k)

    def trunk_features_jvp(self, s):
        """Trunk features and their derivative in s, by forward-mode differentiation."""
        f, df = torch.func.jvp(self.trunk_features, (s,), (torch.ones_like(s),))
        return f, df

    def assemble(self, x0, tau, bf, tf, dtf=None, gain=None):
        """Trajectories (B, M, 2) from branch features bf (B, 2, k) and trunk features tf (M, 2, k) at times tau;
        with the trunk's s-derivative dtf, also their tau-derivatives. gain (B,): the correction's factor
        beta / beta_ref of a range model (None: 1)."""
        s = (tau / self.window)[None, :, None]
        scale = self.corr_scale if gain is None else self.corr_scale * gain[:, None, None]
        n = torch.einsum("bjk,mjk->bmj", bf, tf) + self.bias  # (B, M, 2)
        lin, dlin = self.flow(x0, tau)
        x = lin + s * scale * n
        if dtf is None:
            return x
        dn = torch.einsum("bjk,mjk->bmj", bf, dtf)  # dN/ds
        dx = dlin + scale / self.window * (n + s * dn)
        return x, dx

    def forward(self, x0, tau, par=None):
        """States x0 (B, 2) (and bows par (B, 2) for a range model) and times tau (M,) in [0, T] -> trajectories
        (B, M, 2)."""
        gain = None if par is None else self.gain(par)
        return self.assemble(x0, tau, self.branch_features(x0, par), self.trunk_features(tau / self.window),
                             gain=gain)

    def forward_with_dt(self, x0, tau, par=None):
        """Trajectories and their tau-derivatives, both (B, M, 2)."""
        tf, dtf = self.trunk_features_jvp(tau / self.window)
        gain = None if par is None else self.gain(par)
        return self.assemble(x0, tau, self.branch_features(x0, par), tf, dtf, gain=gain)
