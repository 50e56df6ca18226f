"""The PI-DeepONet: branch on the window's initial state, trunk on time in the window, cartesian-product form.

    x(tau) = R(tau) x0 + s * c * N(x0, s),   s = tau / T,   N_j = <branch_j(x0), trunk_j(s)> + bias_j

R(tau) is the exact flow of the frictionless oscillator (a rotation), so the network learns only what friction
adds; the factor s makes x(0) = x0 exact (hard initial condition). c scales the correction to O(1).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .npnet import NetConfig  # noqa: F401  (torch-free: model files are read without torch)


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
        self.branch = ModifiedMLP(2, cfg.width, cfg.depth, 2 * cfg.k, cfg.ff_branch, cfg.sigma_branch, gen)
        self.trunk = ModifiedMLP(1, cfg.width, cfg.depth, 2 * cfg.k, cfg.ff_trunk, cfg.sigma_trunk, gen)
        self.bias = nn.Parameter(torch.zeros(2))
        self.register_buffer("center", torch.zeros(2))  # state centre and half-range: branch input scaling
        self.register_buffer("halfrange", torch.ones(2))
        self.register_buffer("corr_scale", torch.ones(2))  # c: size of the friction correction per variable
        self.register_buffer("window", torch.tensor(2 * math.pi))  # T, in tau

    def set_scales(self, center, halfrange, corr_scale, window: float):
        self.center.copy_(torch.as_tensor(center))
        self.halfrange.copy_(torch.as_tensor(halfrange))
        self.corr_scale.copy_(torch.as_tensor(corr_scale))
        self.window.fill_(float(window))

    def branch_features(self, x0):
        """(B, 2) states -> (B, 2, k)."""
        return self.branch((x0 - self.center) / self.halfrange).view(-1, 2, self.cfg.k)

    def trunk_features(self, s):
        """(M,) window fractions -> (M, 2, k)."""
        return self.trunk(s[:, None]).view(-1, 2, self.cfg.k) / math.sqrt(self.cfg.k)

    def trunk_features_jvp(self, s):
        """Trunk features and their derivative in s, by forward-mode differentiation."""
        f, df = torch.func.jvp(self.trunk_features, (s,), (torch.ones_like(s),))
        return f, df

    def assemble(self, x0, tau, bf, tf, dtf=None):
        """Trajectories (B, M, 2) from branch features bf (B, 2, k) and trunk features tf (M, 2, k) at times tau;
        with the trunk's s-derivative dtf, also their tau-derivatives."""
        s = (tau / self.window)[None, :, None]
        n = torch.einsum("bjk,mjk->bmj", bf, tf) + self.bias  # (B, M, 2)
        q0, p0 = x0[:, 0:1], x0[:, 1:2]
        c, sn = torch.cos(tau)[None, :], torch.sin(tau)[None, :]
        if self.cfg.linear_flow:
            lq, lp = q0 * c + p0 * sn, p0 * c - q0 * sn
            dlin = torch.stack([lp, -lq], dim=-1)  # R' x0 = (p_lin, -q_lin)
        else:
            lq, lp = q0 * torch.ones_like(c), p0 * torch.ones_like(c)
            dlin = torch.zeros(*lq.shape, 2)
        x = torch.stack([lq, lp], dim=-1) + s * self.corr_scale * n
        if dtf is None:
            return x
        dn = torch.einsum("bjk,mjk->bmj", bf, dtf)  # dN/ds
        dx = dlin + self.corr_scale / self.window * (n + s * dn)
        return x, dx

    def forward(self, x0, tau):
        """States x0 (B, 2) and times tau (M,) in [0, T] -> trajectories (B, M, 2)."""
        return self.assemble(x0, tau, self.branch_features(x0), self.trunk_features(tau / self.window))

    def forward_with_dt(self, x0, tau):
        """Trajectories and their tau-derivatives, both (B, M, 2)."""
        tf, dtf = self.trunk_features_jvp(tau / self.window)
        return self.assemble(x0, tau, self.branch_features(x0), tf, dtf)
