"""What a model covers: the box of states (and, for a range model, of bows) it was trained on, its bounds on what a file
may claim, and the one in-box test."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ... import physics
from ...controls import Curve
from ...scene import Scene

REL_TOL = 1e-6  # beta, v_B, a must match the training scene this closely: the network does not take them as input
MAX_BETA = 1e3  # F_B / w: the playing space ends at 2, the FDM's uniqueness bound at audio rate near 16
MAX_A = 1e6
MAX_WINDOW = 100 * math.pi  # 50 free periods: what training allows (TrainConfig.validate) and a file may claim


def within(x, lo: float, hi: float, rel_tol: float = REL_TOL) -> np.ndarray:
    """Elementwise lo <= x <= hi up to rel_tol of the larger end (a box's side, or a point when lo == hi): the one
    test of a bow against a range, for model files (Domain) and training boxes (ParamBox) alike."""
    # one bow, as a model lookup asks (~7500 times for a chorale): plain arithmetic, without numpy's ~3 us a call
    one = isinstance(x, float | int)
    if lo == hi:
        if one:
            return np.bool_(abs(x - lo) <= 1e-12 + rel_tol * abs(lo))
        return np.isclose(np.asarray(x, float), lo, rtol=rel_tol, atol=1e-12)
    tol = rel_tol * max(abs(hi), 1e-12)
    if one:
        return np.bool_(lo - tol <= x <= hi + tol)
    x = np.asarray(x, float)
    return (x >= lo - tol) & (x <= hi + tol)


# A range model plays the bows below its box down to 0 (see plays_below) only where the box starts in the soft bow,
# at a friction stiffness at most this (a quarter of the way to stick-slip, physics.STIFF: F_B / w 0.107 at a = 100),
# where what friction adds is still about first order in F_B / w: soft-range's bottom, 0.01, plays attacks from F_B 0
# (BENCHMARKS.md, gestures); velocity-loud's, 0.42, is at the boundary
PLAYS_BELOW_STIFFNESS = physics.STIFF / 4


@dataclass
class Domain:
    """Where a model is valid: its dimensionless physics, window, and the states it was trained on."""

    beta: float
    vb: float
    a: float
    window: float  # T in tau
    q_lo: float
    q_hi: float
    p_lo: float
    p_hi: float
    mask: np.ndarray = field(repr=False, default=None)  # (G, G) bool over the box: cells near training states
    # a range model: [beta_lo, beta_hi, vb_lo, vb_hi], the bows it plays (beta, vb above: the box's centre, where the
    # render-time physics check runs); None: a point model, which plays (beta, vb) only
    box: list | None = None
    # a range model whose correction is scaled by beta / beta_ref (npnet.gain) plays bows below its box's bottom down
    # to F_B = 0 (a bow lifted, an attack from rest): what friction adds over a window is first order in beta, so the
    # branch's bow input is held at the bottom (npnet.param_inputs) and the gain carries beta to 0, where the flow is
    # exactly the free rotation. Set from the network's settings (OperatorModel), not stored in files; only for a box
    # whose bottom is soft (PLAYS_BELOW_STIFFNESS). A box that starts at the stick-slip boundary learned other states
    # and another shape of friction: from rest at F_B / w 0.02-0.26, v_B 0.24 velocity-loud (bottom 0.42) left its
    # trained states within 0.06-0.42 s (`bench map`), where soft-range plays those bows.
    plays_below: bool = field(default=False, repr=False, compare=False)

    @property
    def is_range(self) -> bool:
        return self.box is not None

    def check(self) -> None:
        """Refuse a domain no trainer writes (ValueError, one line): every later use (the physics check's RK4 steps
        grow with beta and the window, the mask is indexed by cell) stays bounded and in range."""
        nums = {"beta": self.beta, "vb": self.vb, "a": self.a, "window": self.window, "q_lo": self.q_lo,
                "q_hi": self.q_hi, "p_lo": self.p_lo, "p_hi": self.p_hi}
        for k, v in nums.items():
            try:  # an int past float64 (a forged 2**64) would reach the compiled loops as an object array
                ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(float(v))
            except OverflowError:
                ok = False
            if not ok:
                raise ValueError(f"domain.{k} is {v!r}, not a finite number")
            setattr(self, k, float(v))
        if not (0 <= self.beta <= MAX_BETA and 0 < self.a <= MAX_A and 0 < self.window <= MAX_WINDOW):
            raise ValueError(f"domain beta {self.beta:g}, a {self.a:g}, window {self.window:g} are outside what a "
                             f"model can be trained for (0..{MAX_BETA:g}, 0..{MAX_A:g}, 0..{MAX_WINDOW:.4g})")
        if not (self.q_lo < self.q_hi and self.p_lo < self.p_hi):
            raise ValueError("domain state box is empty")
        m = self.mask
        if m is not None and not (m.ndim == 2 and m.shape[0] == m.shape[1] and 1 <= m.shape[0] <= 4096 and m.any()):
            raise ValueError(f"domain.mask has shape {m.shape} and {int(m.sum())} cells: an empty or odd grid")
        if self.box is not None:
            b = self.box
            try:
                ok = (isinstance(b, list) and len(b) == 4
                      and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(float(x))
                              for x in b) and 0 <= b[0] <= b[1] <= MAX_BETA and b[2] <= b[3])
            except OverflowError:
                ok = False
            if not ok:
                raise ValueError(f"domain.box {b!r} is not [beta_lo, beta_hi, vb_lo, vb_hi]")
            self.box = [float(x) for x in b]

    def beta_in(self, beta) -> np.ndarray:
        """Elementwise: is F_B / w inside this model's box (a point model: equal to its own)?"""
        return within(beta, self.beta, self.beta) if self.box is None else within(beta, *self.box[:2])

    def vb_in(self, vb) -> np.ndarray:
        """Elementwise: is v_B inside this model's box (a point model: equal to its own)?"""
        return within(vb, self.vb, self.vb) if self.box is None else within(vb, *self.box[2:])

    def beta_plays(self, beta) -> np.ndarray:
        """Elementwise: does the model play F_B / w: inside its box, or below it down to 0 (plays_below)?"""
        inside = self.beta_in(beta)
        if not self.plays_below:
            return inside
        b = beta if isinstance(beta, float | int) else np.asarray(beta, float)
        return inside | ((b >= 0) & (b <= self.box[0]))

    @property
    def bow_extent(self) -> float:
        """How much of the playing space the model's bows span: the area of its box in (log F_B / w, v_B), 0 for a
        point model. The renderer prefers the smallest that covers a scene: a narrower model spends its training on
        fewer bows, and validation NMSE from different boxes' own bows does not compare across boxes."""
        if self.box is None:
            return 0.0
        b0, b1, v0, v1 = self.box
        return math.log(max(b1, 1e-12) / max(b0, 1e-12)) * (v1 - v0)

    def spans_played(self, scene: Scene) -> tuple[bool, bool]:
        """A range model: whether it plays the scene's F_B / w span and its v_B span (the curves are linear between
        breakpoints, so their extremes are breakpoint values)."""
        (blo, bhi), (vlo, vhi) = scene.beta_range, scene.vb_range
        return bool(self.beta_plays(blo) and self.beta_plays(bhi)), bool(self.vb_in(vlo) and self.vb_in(vhi))

    def box_contains(self, beta, vb) -> np.ndarray:
        """Elementwise: does the model play the bow (beta, v_B) (a point model: equal to its point; a range model:
        inside its box, or below it in beta, beta_plays)?"""
        return self.beta_plays(beta) & self.vb_in(vb)

    def edge_depth(self, beta_range, vb_range) -> float:
        """How deep inside its box a scene's bows lie: the least distance of their span's ends from the box's edges,
        as a share of the box's span (log F_B / w, v_B); 0 at an edge (or below the box, plays_below), inf for a point
        model. A range model is weakest at its edges (choose.EDGE)."""
        if self.box is None:
            return math.inf
        b0, b1, v0, v1 = self.box
        lb = math.log(max(b1, 1e-12) / max(b0, 1e-12)) or 1.0
        db = min(math.log(max(beta_range[0], 1e-12) / max(b0, 1e-12)), math.log(max(b1, 1e-12) / max(beta_range[1],
                                                                                                    1e-12))) / lb
        dv = min(vb_range[0] - v0, v1 - vb_range[1]) / ((v1 - v0) or 1.0)
        return max(0.0, min(db, dv))

    def describe_bows(self) -> str:
        if self.box is None:
            return f"F_B / w {self.beta:.4g}, v_B {self.vb:g}"
        b0, b1, v0, v1 = self.box
        return f"F_B / w {b0:.4g}..{b1:.4g}, v_B {v0:g}..{v1:g}"

    def contains(self, q, p) -> np.ndarray:
        """Elementwise: is the state (q, p) inside the box and on a cell of the mask?"""
        if isinstance(q, (float, int)) and isinstance(p, (float, int)):
            # one state (a scene's initial one), in plain floats: a score asks this ~1100 times per piece (each
            # note's model choice, tuning and release), and numpy's per-call cost made it 36 ms of a 23 s chorale
            return self._contains_one(float(q), float(p))
        q, p = np.asarray(q, float), np.asarray(p, float)
        inside = (q >= self.q_lo) & (q <= self.q_hi) & (p >= self.p_lo) & (p <= self.p_hi)
        if self.mask is None:
            return inside
        i, j = self.cell(q, p, self.mask.shape[0])
        return inside & self.mask[i, j]

    def _contains_one(self, q: float, p: float) -> bool:
        """contains() for one state, the same rule: the box, then the mask's cell (truncated, clipped indices)."""
        if not (self.q_lo <= q <= self.q_hi and self.p_lo <= p <= self.p_hi):
            return False  # a NaN fails here too
        if self.mask is None:
            return True
        g = self.mask.shape[0]
        i = min(max(int((q - self.q_lo) / (self.q_hi - self.q_lo) * g), 0), g - 1)
        j = min(max(int((p - self.p_lo) / (self.p_hi - self.p_lo) * g), 0), g - 1)
        return bool(self.mask[i, j])

    def cell(self, q, p, grid: int):
        """Indices (i, j) of the cells of a grid x grid partition of the box holding the states (clipped to it)."""
        with np.errstate(invalid="ignore"):
            i = ((np.asarray(q, float) - self.q_lo) / (self.q_hi - self.q_lo) * grid).astype(int, casting="unsafe")
            j = ((np.asarray(p, float) - self.p_lo) / (self.p_hi - self.p_lo) * grid).astype(int, casting="unsafe")
        return np.clip(i, 0, grid - 1), np.clip(j, 0, grid - 1)

    def physics_mismatch(self, scene: Scene) -> list[str]:
        """Reasons the scene's dimensionless physics differs from the model's (empty when it matches). A range model
        covers a scene whose bow stays in its box all the time (the curves are linear between breakpoints, so their
        extremes are breakpoint values)."""
        out = []
        if not math.isclose(scene.a, self.a, rel_tol=REL_TOL, abs_tol=1e-12):
            out.append(f"a = {scene.a:.6g}, model has {self.a:.6g}")
        if self.box is None:
            # a pitch curve whose force follows it (F_B / w held, as a MIDI note's) is still one bow
            (blo, bhi), vb_moves = scene.beta_range, isinstance(scene.vb, Curve)
            if not math.isclose(blo, bhi, rel_tol=1e-9) or vb_moves:
                out.append(f"the bow changes during the scene; this model plays one bow ({self.describe_bows()})")
                return out
            for name, have, want in (("F_B / w", blo, self.beta), ("v_B", scene.vb, self.vb)):
                if not math.isclose(have, want, rel_tol=REL_TOL, abs_tol=1e-12):
                    out.insert(0, f"{name} = {have:.6g}, model has {want:.6g}")
            return out
        b0, b1, v0, v1 = self.box
        (blo, bhi), (vlo, vhi) = scene.beta_range, scene.vb_range
        beta_ok, vb_ok = self.spans_played(scene)
        if not beta_ok:
            out.append(f"F_B / w {span_text(blo, bhi)} leaves the model's {0 if self.plays_below else b0:.4g}..{b1:.4g}")
        if not vb_ok:
            out.append(f"v_B {span_text(vlo, vhi, '.4g')} leaves the model's {v0:g}..{v1:g}")
        return out

    def mismatch(self, scene: Scene) -> list[str]:
        """Reasons this model cannot render the scene (empty when it can)."""
        out = self.physics_mismatch(scene)
        if not self.contains(scene.q0, scene.p0):
            out.append(f"initial state (q0, p0) = ({scene.q0:g}, {scene.p0:g}) is outside the trained states "
                       f"(q in [{self.q_lo:.3g}, {self.q_hi:.3g}], p in [{self.p_lo:.3g}, {self.p_hi:.3g}], on its band)")
        if self.window / physics.dtau(scene.f0_max, scene.sample_rate) < 1:
            out.append(f"the window ({self.window:.3g} in tau) holds no sample at {scene.sample_rate} Hz, f0 "
                       f"{scene.f0_max:g}")
        return out

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("mask")
        d.pop("plays_below")
        return d


def span_text(lo: float, hi: float, fmt: str = ".4g") -> str:
    return f"{lo:{fmt}}" if lo == hi else f"{lo:{fmt}}..{hi:{fmt}}"
