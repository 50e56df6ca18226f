"""How hard the range models' targets are, measured without any network (the FDM only).

    PYTHONPATH=. .venv/bin/python benchmarks/range_limits.py [--box soft|stick] [--part cond,blend]
                                                              [--grids 4x2,8x4,16x4,32x4] [--oversample 5]

Both parts score the targets' held-out bows, the 4 x 4 grid of cell centres of the box (log F_B / w), 1 s from rest
at f0 100, by NMSE(p), the targets' metric.

cond: the metric's conditioning. The FDM at each bow against the FDM at the bow moved by a relative 1e-2, 1e-3,
  1e-4 in F_B / w (then in v_B). Whatever engine plays the box, an error in the bow it effectively plays costs at
  least this much: it says how exact a parametric operator's dependence on the bow must be to meet a target.
blend: the floor of the design "point models blended across a grid of bows" (the other design for a range). Each point
  model is taken as exact: its one-window map is the FDM from the blended state at the grid bow; each window's
  samples and end state are the Lagrange blend (order 2: bilinear, 4: bicubic, in log F_B / w and v_B) of the maps
  at the grid bows around the played bow. The reference is the same window-restarted FDM at the played bow, so what
  is left is the blending's interpolation error alone; trained point models can only add to it.

Both use the numpy FDM (fdm.fdm_batch) at `--oversample` times 44.1 kHz on both sides of each comparison (the
discretisation error cancels to first order: the soft box's conditioning table came out the same to two digits at
x5 and at x10; the blending tables were run at x5 only).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from bowsynth.engines.fdm import fdm_batch

A = 100.0
F0 = 100.0
SR = 44100
SPW = 441  # samples per window of 2 pi at f0 100 (the models' window)
W = 2 * math.pi * F0
BOXES = {"soft": (0.015, 0.4, 0.05, 0.3), "stick": (0.6, 2.0, 0.1, 0.3)}  # the shipped range boxes


def held_out(box) -> np.ndarray:
    """The 4 x 4 grid of cell centres (log beta x v_B), (16, 2)."""
    b0, b1, v0, v1 = box
    lb = math.log(b0) + (np.arange(4) + 0.5) / 4 * (math.log(b1) - math.log(b0))
    v = v0 + (np.arange(4) + 0.5) / 4 * (v1 - v0)
    return np.array([(math.exp(a), b) for a in lb for b in v])


def speaks(p: np.ndarray) -> np.ndarray:
    """Renders whose last period reaches |p| > 0.05 (the note spoke within the second)."""
    return np.abs(p[:, -SPW:]).max(axis=1) > 0.05


def nmse_rows(x: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return ((x - ref) ** 2).mean(axis=1) / ref.var(axis=1)


def conditioning(box, os_: int) -> list[str]:
    T = held_out(box)
    k = 1 / (SR * os_)
    out = []
    for which, name in ((0, "F_B / w"), (1, "v_B")):
        for d in (1e-2, 1e-3, 1e-4):
            bows = np.concatenate([T, T])
            bows[len(T):, which] *= 1 + d
            _, p = fdm_batch(np.zeros(len(bows)), np.zeros(len(bows)), SR, os_, k, W, bows[:, 0] * W, bows[:, 1], A)
            ref, moved = p[:len(T)], p[len(T):]
            e = nmse_rows(moved, ref)
            s = speaks(ref)
            out.append(f"| {name} x (1 + {d:g}) | {np.median(e[s]):.1e} | {e[s].max():.1e} | {s.sum()} |")
    return out


def lagrange(nodes: np.ndarray, x: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """The `order` nodes around x and their Lagrange weights."""
    i = min(max(int(np.searchsorted(nodes, x)) - 1, 0), len(nodes) - 2)
    lo = min(max(i - (order // 2 - 1), 0), len(nodes) - order)
    idx = np.arange(lo, lo + order)
    wts = [math.prod((x - nodes[m]) / (nodes[j] - nodes[m]) for m in idx if m != j) for j in idx]
    return idx, np.array(wts)


def blended(box, n_grid: int, order: int, os_: int, windows: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """NMSE(p) of the blended exact point maps against the window-restarted FDM at each held-out bow, and which
    of those notes speak."""
    b0, b1, v0, v1 = box
    gb, gv = np.linspace(math.log(b0), math.log(b1), n_grid), np.linspace(v0, v1, n_grid)
    T = held_out(box)
    nbrs, wts = [], []
    for beta, vb in T:
        ib, wb = lagrange(gb, math.log(beta), order)
        iv, wv = lagrange(gv, vb, order)
        nbrs.append([(math.exp(gb[i]), gv[j]) for i in ib for j in iv])
        wts.append(np.outer(wb, wv).ravel())
    nbrs, wts = np.array(nbrs), np.array(wts)
    nT, m = len(T), nbrs.shape[1]
    fb = np.concatenate([nbrs[:, :, 0].ravel(), T[:, 0]]) * W
    vb = np.concatenate([nbrs[:, :, 1].ravel(), T[:, 1]])
    k = 1 / (SR * os_)
    xb, xr = np.zeros((nT, 2)), np.zeros((nT, 2))
    pb_all, pr_all = [], []
    for _ in range(windows):
        q0 = np.concatenate([np.repeat(xb[:, 0], m), xr[:, 0]])
        p0 = np.concatenate([np.repeat(xb[:, 1], m), xr[:, 1]])
        q, p = fdm_batch(q0, p0, SPW + 1, os_, k, W, fb, vb, A)
        qb = np.einsum("tms,tm->ts", q[:nT * m].reshape(nT, m, -1), wts)
        pb = np.einsum("tms,tm->ts", p[:nT * m].reshape(nT, m, -1), wts)
        pb_all.append(pb[:, :SPW])
        pr_all.append(p[nT * m:, :SPW])
        xb = np.stack([qb[:, SPW], pb[:, SPW]], axis=1)
        xr = np.stack([q[nT * m:, SPW], p[nT * m:, SPW]], axis=1)
    pb, pr = np.concatenate(pb_all, axis=1), np.concatenate(pr_all, axis=1)
    return nmse_rows(pb, pr), speaks(pr)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--box", choices=sorted(BOXES), default="soft")
    ap.add_argument("--part", default="cond,blend")
    ap.add_argument("--grids", default="4x2,8x2,8x4,16x4,32x4", help="n_grid x order, comma separated")
    ap.add_argument("--oversample", type=int, default=5)
    args = ap.parse_args()
    box = BOXES[args.box]
    print(f"box {args.box}: F_B / w {box[0]:g}-{box[1]:g} x v_B {box[2]:g}-{box[3]:g}, held-out 4 x 4 grid, "
          f"1 s from rest at f0 {F0:g}, FDM x{args.oversample}")
    parts = args.part.split(",")
    if "cond" in parts:
        print("\n| the bow moved by | median NMSE(p) | worst | speaking bows |\n|---|---|---|---|")
        for row in conditioning(box, args.oversample):
            print(row, flush=True)
    if "blend" in parts:
        print("\n| exact point models blended | models in the grid | median NMSE(p) | worst | speaking bows | s |"
              "\n|---|---|---|---|---|---|")
        for spec in args.grids.split(","):
            n, order = (int(x) for x in spec.split("x"))
            t = time.perf_counter()
            e, s = blended(box, n, order, args.oversample)
            kind = {2: "bilinear", 4: "bicubic"}.get(order, f"order {order}")
            print(f"| {n} x {n}, {kind} | {n * n} | {np.median(e[s]):.1e} | {e[s].max():.1e} | {s.sum()} | "
                  f"{time.perf_counter() - t:.0f} |", flush=True)


if __name__ == "__main__":
    main()
