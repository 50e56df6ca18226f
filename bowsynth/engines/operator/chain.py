"""A voice whose bow crosses from one model's box into another's (a crescendo from the soft bow into stick-slip): no
one model covers it, so a chain of models plays it, each from the state the one before left (a window needs nothing
but its start state, as the FDM fallback shows), handed over where the next model has the bow away from its edges."""

from __future__ import annotations

import math

import numpy as np

from ...controls import between, breakpoints
from ...errors import DomainError
from ...render import LazyControls, Played, Render, RenderInfo
from ...scene import Scene
from .choose import EDGE, covering_model, preference
from .modelfile import OperatorModel

# A model keeps the voice at least this long once it took it (unless its box ends): a bow that wavers where two
# boxes are equally deep would otherwise hand over every few windows, and each hand-over starts new windows.
MIN_SEGMENT = 0.05  # s
# The bows are looked at this many times a free period (every 2.5 ms at f0 100). Boxes overlap by 0.01-0.05 in
# F_B / w (models); the listener's crescendo (F_B / w 0.1 -> 1.2 in 1.5 s) moves 0.0018 a look, so it is
# looked at several times inside each overlap.
LOOKS_PER_PERIOD = 4


def _depths(m: OperatorModel, beta: np.ndarray, vb: np.ndarray) -> np.ndarray:
    """Domain.edge_depth of each single bow (beta, v_B), vectorised: how deep inside the box, as a share of its
    span (log F_B / w, v_B); -1 where the box does not play the bow, 0 below it (plays_below)."""
    b0, b1, v0, v1 = m.domain.box
    lb = math.log(b1 / b0) or 1.0
    lbeta = np.log(np.maximum(beta, 1e-12))
    db = np.minimum(lbeta - math.log(b0), math.log(b1) - lbeta) / lb
    dv = np.minimum(vb - v0, v1 - vb) / ((v1 - v0) or 1.0)
    d = np.maximum(0.0, np.minimum(db, dv))
    return np.where(m.domain.box_contains(beta, vb), d, -1.0)


def chain_plan(scene: Scene, models: list[OperatorModel]) -> list[tuple[int, OperatorModel]] | None:
    """The models that play a moving bow no one model covers, as (first sample, model) in order; None where the
    validated range models do not cover every bow of it (or one model does: then it is not a chain). The hand-over
    to another model comes where the current one's bows near its edge (choose.EDGE) or a smaller box has them away
    from its own edges, or where the current one's box ends while the next one's already covers the bow; the next is
    picked in choose.preference's order, as a held bow's model is."""
    if scene.pitch_varies or not scene.varying or covering_model(scene, models) is not None:
        return None
    cands = [m for m in models if m.failure is None and m.domain.is_range
             and math.isclose(m.domain.a, scene.a, rel_tol=1e-6)]
    if len(cands) < 2:
        return None
    n, sr = scene.n_samples, scene.sample_rate
    step = max(1, int(sr / (scene.f0 * LOOKS_PER_PERIOD)))
    # the curves' breakpoints too: between two looks a curve is then a straight line, inside a box where both ends are
    # (sorted(set()), not np.unique: that imports numpy.ma, ms of a render's process)
    bp = np.concatenate([breakpoints(scene.fb)[0], breakpoints(scene.vb)[0]]) * sr
    k = np.array(sorted({*range(0, n, step), n - 1, *(min(max(int(round(b)), 0), n - 1) for b in bp)}))
    t = k / sr
    beta, vb = scene.fb_at(t) / scene.omega, scene.vb_at(t)
    depth = np.stack([_depths(m, beta, vb) for m in cands])  # (models, looks)
    if not (depth.max(axis=0) >= 0).all():
        return None  # a bow no model plays
    extent = [m.domain.bow_extent for m in cands]

    def pick(d: np.ndarray, ok: np.ndarray) -> int:
        """The first of the models ok in choose.preference's order, at depths d; -1 if none."""
        idx = np.flatnonzero(ok)
        return -1 if not idx.size else int(min(idx, key=lambda i: preference(cands[i], float(d[i]))))
    plan: list[list] = [[0, pick(depth[:, 0], depth[:, 0] >= 0)]]
    cur, since, min_len = plan[0][1], 0, MIN_SEGMENT * sr
    for j in range(1, len(k)):
        col = depth[:, j]
        if col[cur] < 0:  # its box ends: the next takes over at the last look where both play the bow
            nxt = pick(col, (col >= 0) & (depth[:, j - 1] >= 0))
            if nxt < 0:
                return None  # a gap between boxes: no state to hand over
            if k[j - 1] <= since:  # the current one took over at that very look: the next plays from there instead
                plan[-1][1] = cur = nxt
                if len(plan) > 1 and plan[-2][1] == cur:
                    plan.pop()
                    since = plan[-1][0]
            else:
                cur, since = nxt, int(k[j - 1])
                plan.append([since, cur])
        elif k[j] - since >= min_len:  # one that has the bow away from its own edges takes over (one only a little
            # deeper is no better) where the current one nears its edge, or where it is a smaller box:
            # the voice follows choose.covering_model's pick for a held bow
            nxt = pick(col, col >= EDGE)
            if nxt >= 0 and (col[cur] < EDGE or extent[nxt] < extent[cur]):
                cur, since = nxt, int(k[j])
                plan.append([since, cur])
    return [(int(s), cands[i]) for s, i in plan] if len(plan) > 1 else None


def _name(m: OperatorModel) -> str:
    return m.path.stem if m.path else m.meta.name


def render_chain(scene: Scene, plan: list[tuple[int, OperatorModel]], play, voice: str = "",
                 sounding=None) -> Render:
    """Render a scene with the models of chain_plan, each on its samples; each next one starts from the last sample
    of the one before (which it plays again as its first). play(scene, model, sounding) -> Render renders a stretch
    with one model (the engine's render, with its fallback). A model that cannot take the state it is handed (outside
    its trained states) stops the render (DomainError) as a voice that leaves its model does. sounding: a held
    note's lock (music.engine_tuning.operator_sounding: its held bow's model's), which the stretches of that model
    play; the others roll free.

    Why: a held note that stops at the space's edge (F_B / w 2.0, v_B 0.12 stopped at 440 Hz) holds its bow with
    stick-heavy and stops through floor-long into halt-edge; with the held stretch in free windows it played 5.0 cents
    off (median per 100 ms frame), with it locked to the physics' period 0.019."""
    n, sr = scene.n_samples, scene.sample_rate
    held = scene.held_bow() if sounding is not None else None
    held_model = covering_model(held) if held is not None else None
    q, p = np.empty(n, np.float32), np.empty(n, np.float32)
    ends = [s for s, _ in plan[1:]] + [n]
    q0, p0 = scene.q0, scene.p0
    parts, notes, secs, fdm = [], [], 0.0, False
    for (s, m), e in zip(plan, ends):
        a = max(s - 1, 0)
        t0, t1 = a / sr, e / sr
        seg = scene.replace(fb=between(scene.fb, t0, t1), vb=between(scene.vb, t0, t1), duration=(e - a) / sr,
                            q0=q0, p0=p0)
        why = m.domain.mismatch(seg)
        if why:
            raise DomainError(f"{voice}model {_name(m)} cannot take the note over at t = {a / sr:.3f} s: "
                              f"{'; '.join(why)}; render with --method fdm")
        # what the engine says of a stretch, it says with the stretch's own times: name the stretch
        where = f"{_name(m)}, in its stretch from t = {t0:.3f} s: "
        try:
            r = play(seg, m, sounding if m is held_model else None)
        except DomainError as err:
            raise DomainError(f"{voice}{where}{err}") from None
        q[a:e], p[a:e] = r.q[:e - a], r.p[:e - a]
        q0, p0 = float(q[e - 1]), float(p[e - 1])
        parts.append((a, e, r))
        notes += [x.replace("note: ", f"note: {voice}{where}", 1) for x in r.info.notes]
        secs += r.seconds
        fdm |= r.method.fdm_fallback

    def controls():
        out = {"fb": np.empty(n), "vb": np.empty(n)}
        for a, e, r in parts:
            for key in out:
                out[key][a:e] = r.controls[key][:e - a]
        return out
    chain = [(round(s / sr, 4), _name(m)) for s, m in plan]
    said = ", ".join(f"{name} from {t:.3f} s" for t, name in chain)
    info = RenderInfo(model_id=" + ".join(m.id for _, m in plan), notes=[f"note: {voice}no one model covers this "
                      f"bow; played by {len(plan)} models in turn: {said}"] + notes, loop=parts[0][2].info.loop,
                      chain=chain)
    return Render(scene, None, q, p, method=Played("operator", fdm_fallback=fdm), seconds=secs,
                  info=info, controls=LazyControls(controls))
