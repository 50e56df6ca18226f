"""The physics' sounding ratio over the bow plane, measured at build time on a grid and interpolated at render time.

A render needs the physics' period at its bow (to lock an operator's windows to it, to solve the f0 of an asked
pitch) without running the reference. `build` solves `tuning.sounding_ratio` (the Richardson-extrapolated FDM from
rest) on a grid of log(F_B / w) x a coordinate of v_B graded toward vb_stop, where the ratio bends fastest, and
writes the table shipped beside the models (`MAP_PATH`); `physics_ratio` reads it and interpolates bicubically
(Catmull-Rom: local, four points a side, no scipy import on the render path) in log(r). Bows where the reference
settles on no oscillation are kept as silent; a bow between silent and sounding grid points is silent where the
bilinear share of sounding neighbours is under one half.

    python -m bowsynth.music.ratio_map build        # `make tables`: ~2 min on two cores
    python -m bowsynth.music.ratio_map check --n 80 # the map against the solver at random bows off its grid
"""

from __future__ import annotations

import functools
import hashlib
import math
import sys
import zipfile
from pathlib import Path

import numpy as np

from .. import physics
from ..errors import ModelFileError, SceneError
from .tuning import Ratio, SilentNoteError
from .. import shipped

MAP_PATH = shipped("models") / "tables" / "physics-ratio.npz"
MAP_A = 100.0  # the friction shape the map (and every shipped model) is measured at
BETA_SPAN = (0.005, 2.1)  # F_B / w: the playing space's 0-2 and a margin; below it r is 1 within 0.02 cents
VB_TOP = 0.30  # v_B: the playing space's 0.28 and a margin
VB_GRADE = 0.004  # y = log(v_B - vb_stop + VB_GRADE): fine steps just above vb_stop, coarse near the top
GRID = (56, 56)  # (beta, v_B) points


def vb_stop(a: float = MAP_A) -> float:
    """v_B = 1 / sqrt(2a): at or below it the friction damps the mass (no note)."""
    return 1.0 / math.sqrt(2.0 * a)


def grid_axes(a: float = MAP_A, n=GRID) -> tuple[np.ndarray, np.ndarray]:
    """(x, y): log(F_B / w) and the graded v_B coordinate of the grid's points, each evenly spaced."""
    vs = vb_stop(a)
    x = np.linspace(math.log(BETA_SPAN[0]), math.log(BETA_SPAN[1]), n[0])
    y = np.linspace(math.log(VB_GRADE * 0.05), math.log(VB_TOP - vs + VB_GRADE), n[1])
    return x, y


def y_of(vb: float, a: float = MAP_A) -> float:
    return math.log(vb - vb_stop(a) + VB_GRADE)


def vb_of(y: np.ndarray, a: float = MAP_A) -> np.ndarray:
    return np.exp(y) - VB_GRADE + vb_stop(a)


def _solve(point):
    from .tuning import measure_ratio

    beta, vb = point
    try:
        r = measure_ratio(beta, vb, MAP_A)
        return r.r, r.settle_periods, r.amplitude
    except SilentNoteError:
        return math.nan, math.nan, math.nan


def _solve_all(points):
    return [_solve(p) for p in points]


CHUNK = 32  # grid points per task


def build(path: Path = MAP_PATH, n=GRID, workers: int = 2, address: str | None = None) -> Path:
    """Solve the ratio at every grid point (the reference, at build time only) and write the table; the points in
    tasks of CHUNK on Ray (io.cluster.Pool: `workers` here, or the cluster at `address`)."""
    from ..io.cluster import Pool

    x, y = grid_axes(MAP_A, n)
    vbs = vb_of(y)
    points = [(float(math.exp(xi)), float(v)) for xi in x for v in vbs]
    chunks = [points[a:a + CHUNK] for a in range(0, len(points), CHUNK)]
    got = [None] * len(chunks)
    with Pool(workers, address) as pool:
        for i, res in pool.map(_solve_all, chunks):
            got[i] = res
    got = np.array([r for chunk in got for r in chunk], dtype=float).reshape(n[0], n[1], 3)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, x=x, y=y, r=got[..., 0], settle=got[..., 1], amplitude=got[..., 2], a=np.array(MAP_A),
             grade=np.array(VB_GRADE))
    tmp.replace(path)
    return path


class RatioMap:
    """The shipped table: `ratio(beta, vb)` a tuning.Ratio, SilentNoteError where the physics does not speak."""

    def __init__(self, path: Path = MAP_PATH):
        try:
            with np.load(path, allow_pickle=False) as z:
                self.x, self.y = np.asarray(z["x"], float), np.asarray(z["y"], float)
                r, settle, amp = (np.asarray(z[k], float) for k in ("r", "settle", "amplitude"))
                self.a, grade = float(z["a"]), float(z["grade"])
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as e:
            raise ModelFileError(f"the physics' pitch map {path} is missing or unreadable ({e}): `make tables` "
                                 f"rebuilds it") from None
        shape = (len(self.x), len(self.y))
        if (r.shape != shape or settle.shape != shape or amp.shape != shape or grade != VB_GRADE
                or not np.all(np.isfinite(self.x)) or not np.all(np.diff(self.x) > 0) or not np.all(np.diff(self.y) > 0)
                or np.any(r[np.isfinite(r)] <= 0) or np.any(r[np.isfinite(r)] > 1.0 + 1e-9)):
            raise ModelFileError(f"the physics' pitch map {path} is not a table this version reads: `make tables` "
                                 f"rebuilds it")
        self.digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
        self.speaks = np.isfinite(r).astype(float)
        self.logr = _padded(_filled(np.log(np.where(np.isfinite(r), r, np.nan))))
        self.logsettle = _padded(_filled(np.log(np.where(np.isfinite(settle), np.maximum(settle, 1.0), np.nan))))
        self.amp = _padded(_filled(amp))

    def covers(self, beta: float, vb: float, a: float) -> bool:
        return (math.isclose(a, self.a, rel_tol=1e-9) and BETA_SPAN[0] <= beta <= BETA_SPAN[1]
                and vb <= VB_TOP)

    def ratio(self, beta: float, vb: float, a: float = MAP_A) -> Ratio:
        beta, vb, a = float(beta), float(vb), float(a)
        for name, v in (("F_B / w", beta), ("v_B", vb), ("a", a)):
            if not math.isfinite(v):
                raise SceneError(f"{name} must be finite, got {v}")
        if beta == 0:
            raise SilentNoteError("the note does not speak: F_B = 0, no bow on the mass")
        if math.isclose(a, self.a, rel_tol=1e-9) and vb <= vb_stop(a):
            raise SilentNoteError(f"the note does not speak: v_B = {vb:g} m/s is at or below 1/sqrt(2a) = "
                                  f"{vb_stop(a):.3g} m/s, where the friction damps the mass (a bow stop): bow faster")
        if not self.covers(beta, vb, a):
            raise OffMapError(f"the physics' pitch map covers F_B / w {BETA_SPAN[0]:g}-{BETA_SPAN[1]:g} and v_B up to "
                              f"{VB_TOP:g} at a = {self.a:g}, not F_B / w {beta:.4g}, v_B {vb:g}, a {a:g}: render "
                              f"with --method fdm")
        fx = (math.log(beta) - self.x[0]) / (self.x[1] - self.x[0])
        fy = (y_of(vb, a) - self.y[0]) / (self.y[1] - self.y[0])
        fy = max(fy, 0.0)  # below the first row (within 1e-4 of vb_stop): the first row's
        if _bilinear(self.speaks, fx, fy) < 0.5:
            raise SilentNoteError(f"the note does not speak: the bow settles on no oscillation at F_B / w = {beta:.4g},"
                                  f" v_B = {vb:g} (it damps the mass, or the note grows too slowly: bow slower or "
                                  f"press harder)")
        return Ratio(r=float(math.exp(_cubic(self.logr, fx, fy))),
                     settle_periods=float(math.exp(_cubic(self.logsettle, fx, fy))),
                     amplitude=float(_cubic(self.amp, fx, fy)), beta=beta, vb=vb, a=a)


class OffMapError(SceneError):
    """A bow outside the shipped map: no physics' period is known there without the reference."""


def _filled(v: np.ndarray) -> np.ndarray:
    """NaN points (silent bows) filled from their nearest sounding neighbour along v_B, then beta: the cubic's stencil
    near the border of the silent region reads continued values rather than holes."""
    v = v.copy()
    for axis in (1, 0):
        w = np.moveaxis(v, axis, -1)
        idx = np.arange(w.shape[-1])
        for row in w:
            ok = np.isfinite(row)
            if ok.any() and not ok.all():
                row[~ok] = np.interp(idx[~ok], idx[ok], row[ok])
    v[~np.isfinite(v)] = np.nanmean(v) if np.isfinite(v).any() else 0.0
    return v


def _padded(v: np.ndarray) -> np.ndarray:
    """v with one ghost point each side along both axes, extrapolated by the quadratic through the three edge points
    (3 v0 - 3 v1 + v2): a cubic's stencil at the grid's edge then keeps its order (a repeated edge point cost 6.7
    cents at the heavy fast corner)."""
    for axis in (0, 1):
        w = np.moveaxis(v, axis, 0)
        lo = 3 * w[0] - 3 * w[1] + w[2]
        hi = 3 * w[-1] - 3 * w[-2] + w[-3]
        v = np.moveaxis(np.concatenate([lo[None], w, hi[None]]), 0, axis)
    return v


def _weights(t: float) -> np.ndarray:
    """Catmull-Rom weights of the four points around a fraction t in [0, 1]."""
    t2, t3 = t * t, t * t * t
    return 0.5 * np.array([-t3 + 2 * t2 - t, 3 * t3 - 5 * t2 + 2, -3 * t3 + 4 * t2 + t, t3 - t2])


def _stencil(f: float, n: int) -> tuple[slice, float]:
    """The four points (of a padded axis of n + 2) around grid fraction f, and f's place between the middle two."""
    i = min(max(int(math.floor(f)), 0), n - 2)
    return slice(i, i + 4), min(max(f - i, 0.0), 1.0)


def _cubic(v: np.ndarray, fx: float, fy: float) -> float:
    """Catmull-Rom in both axes of a padded table (_padded) at grid fractions (fx, fy)."""
    ix, tx = _stencil(fx, v.shape[0] - 2)
    iy, ty = _stencil(fy, v.shape[1] - 2)
    return float(_weights(tx) @ v[ix, iy] @ _weights(ty))


def _bilinear(v: np.ndarray, fx: float, fy: float) -> float:
    i, j = min(max(int(fx), 0), v.shape[0] - 2), min(max(int(fy), 0), v.shape[1] - 2)
    tx, ty = min(max(fx - i, 0.0), 1.0), min(max(fy - j, 0.0), 1.0)
    return float((1 - tx) * ((1 - ty) * v[i, j] + ty * v[i, j + 1])
                 + tx * ((1 - ty) * v[i + 1, j] + ty * v[i + 1, j + 1]))


@functools.lru_cache(maxsize=2)
def shipped(path: str = str(MAP_PATH)) -> RatioMap:
    return RatioMap(Path(path))


@functools.lru_cache(maxsize=8192)
def physics_ratio(beta: float, vb: float, a: float = MAP_A) -> Ratio:
    """The physics' sounding ratio at a bow from the shipped map (no reference run): what the render path asks
    where `tuning.sounding_ratio` would solve. SilentNoteError where the note does not speak, OffMapError off the
    map."""
    return shipped().ratio(beta, vb, a)


def map_ratio(beta: float, vb: float, a: float, f0: float) -> float:
    """The physics' sounding ratio from the shipped map, as `tuning.tune(ratio=...)` takes it (f0 unused): what a note
    asked at a pitch is tuned with before the engine that plays it is known (`request.make_scene`), or where no
    operator model covers it. Off the map (another friction shape a) the reference's solve (physics_or_solve): no
    operator model plays there, only the FDM."""
    return physics_or_solve(beta, vb, a).r


def physics_or_solve(beta: float, vb: float, a: float = MAP_A) -> Ratio:
    """The shipped map's ratio where it covers the bow; off it (another friction shape a), the reference's solve
    (`tuning.sounding_ratio`): no operator model plays there, so only the FDM (the reference engine) does."""
    from .tuning import sounding_ratio

    try:
        return physics_ratio(beta, vb, a)
    except OffMapError:
        return sounding_ratio(beta, vb, a)


map_ratio.physics = physics_or_solve


def check(n: int = 80, seed: int = 0) -> dict:
    """The map against the solver at n random bows off its grid (uniform in log F_B / w and in v_B over the playing
    space): cents of each, and the bows where the two disagree on whether the note speaks."""
    from .tuning import sounding_ratio

    rng = np.random.default_rng(seed)
    m = shipped()
    errs, disagree = [], []
    for _ in range(n):
        beta = float(math.exp(rng.uniform(math.log(0.02), math.log(2.0))))
        vb = float(rng.uniform(vb_stop() * 1.001, 0.28))
        try:
            truth = sounding_ratio(beta, vb).r
        except SilentNoteError:
            truth = None
        try:
            got = m.ratio(beta, vb).r
        except SilentNoteError:
            got = None
        if (truth is None) != (got is None):
            disagree.append((beta, vb, truth, got))
        elif truth is not None:
            errs.append((1200 * math.log2(got / truth), beta, vb))
    c = np.abs([e[0] for e in errs])
    return {"n": n, "sounding": len(errs), "median_cents": float(np.median(c)), "p90_cents": float(np.quantile(c, 0.9)),
            "worst": max(errs, key=lambda e: abs(e[0])), "disagree": disagree}


if __name__ == "__main__":
    if sys.argv[1:2] == ["build"]:
        opt = lambda flag, default: sys.argv[sys.argv.index(flag) + 1] if flag in sys.argv else default  # noqa: E731
        print(build(workers=int(opt("--workers", 2)), address=opt("--address", None)))
    elif sys.argv[1:2] == ["check"]:
        k = sys.argv.index("--n") + 1 if "--n" in sys.argv else None
        print(check(int(sys.argv[k]) if k else 80))
    else:
        sys.exit("usage: python -m bowsynth.music.ratio_map build [--workers N] [--address HOST:PORT] | check [--n N]")
