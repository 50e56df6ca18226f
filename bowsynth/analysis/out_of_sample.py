"""How a model does away from its training data: from band states it never started at, from fractional windows, at
bows between its training points (a range model), window by window."""

from __future__ import annotations

import math

import numpy as np

from .. import physics
from ..engines.fdm import TRUTH_OVERSAMPLE, render_fdm
from ..scene import Scene
from .bench import score_render
from ..metrics import nmse


def band_states(model, n: int, rng: np.random.Generator, away: float = 0.25) -> np.ndarray:
    """n states drawn uniformly over the cells of the model's domain mask (the band, with its margin), each at least
    `away` times the band's half-size from rest (0, 0): a note that starts from a moving mass."""
    d = model.domain
    g = d.mask.shape[0]
    cells = np.argwhere(d.mask)
    half = 0.5 * min(d.q_hi - d.q_lo, d.p_hi - d.p_lo)
    out = np.empty((0, 2))
    while len(out) < n:
        c = cells[rng.integers(len(cells), size=4 * n)] + rng.random((4 * n, 2))
        x = np.stack([d.q_lo + c[:, 0] / g * (d.q_hi - d.q_lo), d.p_lo + c[:, 1] / g * (d.p_hi - d.p_lo)], 1)
        x = x[d.contains(x[:, 0], x[:, 1]) & (np.hypot(x[:, 0], x[:, 1]) > away * half)]
        out = np.concatenate([out, x])
    return out[:n]


def fractional_starts(scene: Scene, window: float, periods=(2, 20), fractions=(0.25, 0.5, 0.75)) -> np.ndarray:
    """States of the render from rest (FDM x100) at t = (m + f) T: on the trained trajectory, but where no window of
    that render starts (its windows start at whole multiples of T), in the onset (m = 2) and on the limit cycle."""
    t_win = window / scene.omega
    t_max = (max(periods) + 1) * t_win
    ref = render_fdm(scene.replace(duration=t_max, sample_rate=scene.sample_rate * 4, q0=0.0, p0=0.0),
                     oversample=TRUTH_OVERSAMPLE // 4)
    idx = [int(round((m + f) * t_win * ref.scene.sample_rate)) for m in periods for f in fractions]
    return np.stack([ref.q[idx], ref.p[idx]], 1)


def _one_case(model, scene: Scene) -> dict:
    from ..engines.operator.engine import render_operator
    from ..errors import DomainError

    ref = render_fdm(scene, oversample=TRUTH_OVERSAMPLE)
    try:
        r = render_operator(scene, model=model)
    except DomainError as e:
        return {"failed": str(e)}
    return score_render(r, ref)


def _summary(label: str, scores: list[dict], detail: str) -> dict:
    ok = [s for s in scores if "failed" not in s]
    med = lambda k: float(np.median([s[k] for s in ok])) if ok else math.nan  # noqa: E731
    return {"case": label, "detail": detail, "n": len(scores), "failed": len(scores) - len(ok),
            "nmse_p_median": med("nmse_p"), "nmse_p_worst": max((s["nmse_p"] for s in ok), default=math.nan),
            "cents_worst": max((abs(s["cents"]) for s in ok), default=math.nan), "harmonic_db_median": med("harmonic_db"),
            "lsd_db_median": med("lsd_db")}


def bench_out_of_sample(model, duration: float = 1.0, n_states: int = 8, seed: int = 0) -> list[dict]:
    """Renders of `model` from initial states and at sample offsets training never used, each against an FDM x100 of
    the same scene; the first row is the in-sample render from rest at the model's own scene, for scale."""
    sc = Scene(**{**model.meta.scene, "duration": duration})
    rng = np.random.default_rng(seed)
    rows = [_summary("in sample: from rest, own scene", [_one_case(model, sc)], f"f0 {sc.f0:g}, {sc.sample_rate} Hz")]
    x = band_states(model, n_states, rng)
    rows.append(_summary("random band states, away from rest", [_one_case(model, sc.replace(q0=q, p0=p)) for q, p in x],
                         f"{n_states} states, seed {seed}"))
    x = fractional_starts(sc, model.domain.window)
    rows.append(_summary("rest trajectory at (m + f) T", [_one_case(model, sc.replace(q0=q, p0=p)) for q, p in x],
                         "m 2, 20; f 0.25, 0.5, 0.75"))
    for rate in (48_000, 96_000):
        s = sc.replace(sample_rate=rate)
        x0 = band_states(model, 2, rng)
        rows.append(_summary(f"{rate // 1000} kHz", [_one_case(model, s)] +
                             [_one_case(model, s.replace(q0=q, p0=p)) for q, p in x0], "from rest + 2 band states"))
    cases = []
    for f0 in (130.0, 200.0):  # T / dtau = 339.2 and 220.5 samples at 44.1 kHz: windows of two lengths
        s = sc.replace(f0=f0, fb=model.domain.beta * physics.omega(f0))
        cases += [_one_case(model, s)] + [_one_case(model, s.replace(q0=q, p0=p)) for q, p in band_states(model, 1, rng)]
    rows.append(_summary("other pitches, T / dtau not whole", cases, "f0 130, 200 (same F_B / w): rest + 1 band state"))
    return rows


def window_errors(model, x0: np.ndarray, scene: Scene) -> np.ndarray:
    """NMSE(p) of the operator's one-window prediction from each state against an FDM x100 over the same window."""
    from ..engines.operator.rollout import rollout_states

    dtau = scene.dtau
    n = int(math.floor(model.domain.window / dtau)) + 1  # the window's samples and the next window's first
    _, p, _ = rollout_states(model, x0, n, dtau, check_domain=False)
    out = []
    for i, (q0, p0) in enumerate(x0):
        ref = render_fdm(scene.replace(q0=float(q0), p0=float(p0), duration=n / scene.sample_rate),
                         oversample=TRUTH_OVERSAMPLE)
        out.append(nmse(p[i], ref.p))
    return np.array(out)


def band_distance(model, x: np.ndarray, scene: Scene) -> np.ndarray:
    """Distance of each state from the band (the audio-rate FDM's states over 1 s from the scene's initial state),
    as a fraction of the domain's box (each axis scaled by the box's side)."""
    d = model.domain
    r = render_fdm(scene.replace(duration=1.0))
    band = np.stack([r.q, r.p], 1)
    side = np.array([d.q_hi - d.q_lo, d.p_hi - d.p_lo])
    return np.array([np.hypot(*((band - xi) / side).T).min() for xi in np.asarray(x, float)])


NEAR = 0.025  # of the box: the training sampler's noise is 2.5 % of the band's range (sd); the mask reaches ~6 %


def bench_windows(model, n_states: int = 64, seed: int = 1) -> list[dict]:
    """One-window errors at the window starts of the render from rest (the states training took exactly) and at
    held-out band states (drawn over the domain's mask, not on that trajectory), split by their distance from the
    band: training draws its states near the band, while the domain's mask, which a render is allowed to visit,
    reaches farther."""
    sc = Scene(**model.meta.scene)
    n_win = int(math.floor(model.domain.window / sc.dtau))
    path = render_fdm(sc.replace(duration=1.0), oversample=TRUTH_OVERSAMPLE)
    starts = np.stack([path.q[::n_win], path.p[::n_win]], 1)[:n_states]
    held = band_states(model, n_states, np.random.default_rng(seed), away=0.0)
    dist = band_distance(model, held, sc)
    rows = []
    for label, x0 in (("window starts of the render from rest (trained)", starts),
                      (f"held-out band states within {NEAR:.1%} of the box from the band", held[dist < NEAR]),
                      ("held-out band states farther (the mask's margin)", held[dist >= NEAR])):
        if len(x0) == 0:
            continue
        e = window_errors(model, x0, sc)
        rows.append({"states": label, "n": len(e), "nmse_p_median": float(np.median(e)), "nmse_p_worst": float(e.max())})
    return rows


def bench_parameter_points(model, pitches=(100.0,), n: int = 4, duration: float = 1.0) -> list[dict] | None:
    """Held-out bows of a range model: the n x n grid of cell centres of its box (log beta; its training bows are a
    Latin hypercube of another seed) at each pitch, `duration` s from rest, operator against the FDM x100: NMSE(p) and
    the pitch error where the note speaks (training.ranges.speaks), quiet and finite where it does not. None for a
    point model (one bow: nothing to hold out)."""
    if not model.domain.is_range:
        return None
    from ..engines.operator.engine import render_operator
    from ..training.ranges import ParamBox, speaks
    from ..metrics import cents, f0_estimate

    b0, b1, v0, v1 = model.domain.box
    box = ParamBox(b0, b1, v0, v1, model.domain.a)
    rows = []
    for f0 in pitches:
        for beta, vb in box.grid(n):
            sc = Scene(f0=f0, fb=float(beta) * physics.omega(f0), vb=float(vb), a=box.a, duration=duration)
            ref = render_fdm(sc, oversample=TRUTH_OVERSAMPLE)
            r = render_operator(sc, model=model, fallback="fdm")
            row = {"f0": f0, "beta": float(beta), "vb": float(vb), "speaks": bool(speaks(beta, vb, box.a, f0, duration)),
                   "method": r.method, "finite": bool(np.isfinite(r.p).all()),
                   "max_abs_p": float(np.max(np.abs(r.p))), "ref_max_abs_p": float(np.max(np.abs(ref.p)))}
            if row["speaks"]:
                row["nmse"] = float(nmse(r.p, ref.p))
                row["cents"] = float(cents(f0_estimate(r.q, sc.sample_rate), f0_estimate(ref.q, sc.sample_rate)))
            rows.append(row)
    return rows


def parameter_summary(rows: list[dict]) -> dict:
    """Median and worst NMSE(p) and worst |cents| over the speaking bows; the silent ones all finite?"""
    spk = [r for r in rows if r["speaks"]]
    vals = np.array([r["nmse"] for r in spk])
    return {"points": len(rows), "speaking": len(spk),
            "median_nmse": float(np.median(vals)) if len(vals) else None,
            "worst_nmse": float(np.max(vals)) if len(vals) else None,
            "worst_cents": float(np.max(np.abs([r["cents"] for r in spk]))) if spk else None,
            "quiet_all_finite": all(r["finite"] for r in rows if not r["speaks"]),
            "fdm_fallbacks": sum(r["method"] != "operator" for r in rows)}
