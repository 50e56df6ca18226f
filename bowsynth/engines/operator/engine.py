"""The operator as an engine: a scene (or many, batched) in, a Render out; the covering model chosen, the bow
checked before the loop, a voice that leaves its model finished by the FDM when asked."""

from __future__ import annotations

import functools
import math
import time
from pathlib import Path

import numpy as np

from ... import physics
from ...errors import DomainError, ModelFileError, UsageError
from ...render import LazyControls, Played, Render, RenderInfo
from ...scene import Scene
from .basis import numpy_operator
from .check import CHECK_WINDOWS, MISLABEL_MARGIN, PHYSICS_MAX_ERROR, check_physics, claim_verdict
from .choose import (bow_exit, as_model, available_models, covering_model, find_model, first_bow_outside,
                     partial_model, train_hint, unreadable_notes)
from .grid import from_grid, needs_whole_windows, to_grid, to_output_in_place, whole_window_scene
from .modelfile import OperatorModel
from .onset import mute_from, rest_onset, ring_down
from .rollout import applied_controls, length_buckets, prepare, rollout_states, scene_bows
from .windows import FAIL_BOW, FAIL_DOMAIN, FAIL_MUTE, FAILURES, locked_window, window_bounds


def resolve_model(scene: Scene, model, models: list[OperatorModel] | None = None, fallback: str = "none"):
    if model is None:
        try:
            return find_model(scene, models)
        except DomainError:
            part = partial_model(scene, models) if fallback == "fdm" else None
            if part is None:
                raise
            return part[0]
    model = as_model(model)
    why = model.domain.mismatch(scene)
    where = first_bow_outside(model, scene) if why and model.domain.is_range else None
    if where and where[0] > 0 and fallback == "fdm" and model.domain.contains(scene.q0, scene.p0):
        return model  # it plays the opening; the FDM the rest
    if where:  # name the parameter, its value and the time it leaves the range
        why = [f"{where[1]} leaves its {model.domain.describe_bows()}"] + [
            w for w in why if not w.startswith(("F_B", "v_B"))]
    if why:
        raise DomainError(f"model {model.path or model.meta.name} does not cover this scene: {'; '.join(why)}. "
                          f"Train one with `{train_hint(scene)}`, or render with --method fdm")
    return model


def _finish(scene: Scene, q, p, fail, fallback: str, voice: str = "") -> list[str]:
    """A voice whose rollout stopped: finish it with the FDM from its last good sample (fallback 'fdm', in place;
    returns the note to show) or raise DomainError."""
    at, code = int(fail[0]), int(fail[1])
    if at < 0 or at >= scene.n_samples:  # a shorter voice of a batch may fail after its own end
        return []
    why = f"{FAILURES[code]} at t = {at / scene.sample_rate:.4f} s"
    if code == FAIL_BOW and len(fail) > 2 and fail[2]:
        why = f"{FAILURES[code]}: {fail[2]}"
    if fallback != "fdm":
        raise DomainError(f"{voice}{why}; the render was stopped (use --fallback "
                          f"fdm to finish with the FDM, or --method fdm)")
    from ..fdm import render_fdm

    start = max(at - 1, 0)
    q0, p0 = (float(q[start]), float(p[start])) if at else (scene.q0, scene.p0)
    # the FDM goes on from sample `start` with the curves as they stand there
    rest = render_fdm(scene.after(start / scene.sample_rate, duration=(scene.n_samples - start) / scene.sample_rate,
                                  q0=q0, p0=p0))
    q[start:], p[start:] = rest.q[:scene.n_samples - start], rest.p[:scene.n_samples - start]
    return [f"note: {voice}{why}; finished with the FDM from there"]


# A voice whose samples leave the box of the model's trained states by more than this share of its span has left what
# the model knows, even where each window's start stays inside (the loops check starts only). Measured (2 s
# notes from rest at 65-880 Hz): every render that sounds right stays inside the box (by 2-39 % of the span); the
# stick-slip point models at 440/880 Hz, whose rollouts break out of the stick-slip cycle while their window starts
# stay in the domain, go 31-61 % of the span beyond it (p peaks at 1.6 against the truth's 0.26): a loud wrong note.
# 10 % lies between the two with room on both sides (the tests' tiny models wander a few per cent past their boxes).
BOX_SLACK = 0.1


def _box_exit(m: OperatorModel, sc: Scene, q, p, window: float | None = None) -> int | None:
    """The first sample of the window whose samples leave the model's box of trained states (by BOX_SLACK of its
    span), or None. window: the voice's window in tau (None: the model's T)."""
    d = m.domain
    sq, sp = BOX_SLACK * (d.q_hi - d.q_lo), BOX_SLACK * (d.p_hi - d.p_lo)
    # four reductions first (a note inside its box, the usual case: 0.02 ms, where the masks below take 0.3 ms for
    # 5 s); they propagate NaN, and a voice with a NaN (stopped) takes the masks, which skip it
    bounds = np.array([np.min(q), np.max(q), np.min(p), np.max(p)], dtype=float) if len(q) else np.zeros(4)
    if (np.isfinite(bounds).all() and bounds[0] >= d.q_lo - sq and bounds[1] <= d.q_hi + sq
            and bounds[2] >= d.p_lo - sp and bounds[3] <= d.p_hi + sp):
        return None
    with np.errstate(invalid="ignore"):
        out = (q < d.q_lo - sq) | (q > d.q_hi + sq) | (p < d.p_lo - sp) | (p > d.p_hi + sp)
    j = np.flatnonzero(out)
    if not j.size:
        return None
    starts, _ = window_bounds(numpy_operator(m).samples_per_window(sc.dtau, window), sc.n_samples)
    return int(starts[np.searchsorted(starts, j[0], side="right") - 1])


def _physics_notes(m: OperatorModel) -> list[str]:
    """Check a model read from a file against the physics its metadata claims (check_physics). A model that passed
    its validation must pass: else ModelFileError. One whose validation failed (never picked by default, so it was
    asked for by name) renders with a note instead. Models built in memory (the trainer's) are not checked here."""
    if not m.from_file:
        return []
    err = check_physics(m)
    if err <= PHYSICS_MAX_ERROR:  # NaN fails too
        return []
    d = m.domain
    what = (f"its first {CHECK_WINDOWS} windows differ from the physics it claims (F_B / w = {d.beta:.4g}, "
            f"v_B = {d.vb:g}, a = {d.a:g}) by {err:.3g} (relative mean square; the limit is {PHYSICS_MAX_ERROR:g})")
    if m.failure is None and math.isfinite(err):
        # the neighbours' checks cost 5 ms (0.13 s where 16 periods of quarter windows decide): kept by the file
        honest, b_alt, v_alt = claim_verdict(m, err)
        if honest:  # an inaccuracy, not a lie: the claimed bow is still the one the weights play
            return [f"note: model {m.path or m.meta.name}: {what}, but its windows fit the claimed bow "
                    f"{MISLABEL_MARGIN:g}x better than bows 10 % away: an inaccurate onset, not a mislabelled file"]
        raise ModelFileError(f"model {m.path or m.meta.name} does not do what it claims: {what}, and they fit "
                             f"F_B / w = {b_alt:.4g}, v_B = {v_alt:.4g} as well or better: its metadata does not "
                             f"describe its weights. Retrain it, or render with --method fdm")
    if m.failure is None:
        raise ModelFileError(f"model {m.path or m.meta.name} does not do what it claims: {what}; its metadata does "
                             f"not describe its weights. Retrain it, or render with --method fdm")
    return [f"note: model {m.path or m.meta.name} is not validated ({m.failure}) and {what}: expect a poor render"]


def render_operator(scene, model=None, fallback: str = "none", sounding=None):
    """Render one scene (or a list of scenes, batched in one rollout) with a trained operator.

    model: an OperatorModel, a path, or None to pick the best validated model that covers the scene (see
    find_model). A range model follows the scene's bow curves window by window (scene_bows); a point model plays
    scenes of its one bow. fallback='fdm' finishes a rollout that leaves the model's domain, or a bow that leaves
    every model's range, with the FDM (and says so in info.notes); 'none' raises DomainError. Every render first
    checks the model's physics (check_physics) and raises ModelFileError if the model does not do what its metadata
    claims. The arrays of an operator render are float32, the network's precision.
    sounding: the frequency (Hz) each voice's note sounds at (one for a scene, a list for a list, None where not
    known): its windows are then locked to that period (windows.locked_window); None: windows of the trained T.
    """
    if fallback not in ("none", "fdm"):
        raise UsageError(f"fallback must be none or fdm, got {fallback!r}")
    if isinstance(scene, (list, tuple)):
        return render_operator_batch(list(scene), model=model, fallback=fallback, sounding=sounding)
    return render_operator_batch([scene], model=model, fallback=fallback, _single=True, sounding=[sounding])[0]


def _applied(sc: Scene, grid, op, bows, leave, window=None) -> dict:
    """The controls a voice's render applied, per output sample (Render.controls, computed when read): the bow of
    each window on the voice's grid, and the scene's curves where the FDM played the rest."""
    g, ratio = grid
    ns = sc.n_samples
    ctrl = applied_controls(g, op.samples_per_window(g.dtau, window), bows)
    if ratio != 1:
        j = to_grid(ns, ratio, g.n_samples)
        ctrl = {k: v[j] for k, v in ctrl.items()}
    if leave is not None:  # the FDM played the rest: its controls are the curves themselves
        at = from_grid(leave[0], ratio)
        tt = np.arange(at, ns) / sc.sample_rate
        ctrl["fb"][at:], ctrl["vb"][at:] = sc.fb_at(tt), sc.vb_at(tt)
    return ctrl


def _applied_after_rest(sc: Scene, m: OperatorModel, h: int, rest, window=None) -> dict:
    """_applied for a voice whose first h samples the flow at rest played (with the bows of the note's windows) and
    the operator the rest (`rest`: its _applied, or None where the flow played the whole note)."""
    spw = numpy_operator(m).samples_per_window(sc.dtau, window)
    ctrl = applied_controls(sc, spw, scene_bows(sc, spw))
    if rest is not None:
        after = rest()
        for k in ctrl:
            ctrl[k][h:] = after[k][:sc.n_samples - h]
    return ctrl


def _voice_bows(m: OperatorModel, scenes: list[Scene], windows: list):
    """Per voice: the bows of its windows (padded to a common length) and where the bow first leaves the model's
    range ((sample, what) or None: only a --fallback fdm render gets here with one). windows: each voice's window
    in tau (None: the model's T)."""
    op = numpy_operator(m)
    rows, leave = [], []
    for sc, win in zip(scenes, windows):
        spw = op.samples_per_window(sc.dtau, win)
        bows = scene_bows(sc, spw)
        out = None
        if m.domain.is_range:
            exit_ = bow_exit(m, sc, spw, bows)
            if exit_ is not None:
                out = exit_[1:]
                lo_b, hi_b, lo_v, hi_v = m.domain.box
                bows = np.stack([np.clip(bows[:, 0], lo_b, hi_b), np.clip(bows[:, 1], lo_v, hi_v)], axis=1)
        rows.append(bows)
        leave.append(out)
    W = max(len(r) for r in rows)
    par = np.stack([np.concatenate([r, np.repeat(r[-1:], W - len(r), axis=0)]) for r in rows])
    return par, rows, leave


def _model_name(m: OperatorModel) -> str:
    return m.path.stem if m.path else m.meta.name


def _handover_note(voice: str, m: OperatorModel, why: str, r: Render) -> str:
    """The note of a voice that left model m's trained states (why: what and when) and that r's model played."""
    by = Path(r.info.model_path).stem if r.info.model_path else r.info.model_id
    return f"note: {voice}{_model_name(m)}: {why}; played by {by} instead"


def voice_window(m: OperatorModel, scene: Scene, sounding: float | None) -> float | None:
    """The window (tau) a voice of this scene rolls with: locked to the period it sounds at where the caller knows
    it (windows.locked_window: a held bow's; a score's note until its bow stop); else None, the model's trained T."""
    if sounding is None or scene.pitch_varies or not sounding > 0:
        return None
    T = numpy_operator(m).window
    w = locked_window(T, scene.f0, sounding)
    return None if w >= T else w


def render_operator_batch(scenes: list[Scene], model=None, fallback: str = "none", _single: bool = False,
                          _models: list[OperatorModel] | None = None, _labels: list[int] | None = None,
                          sounding=None) -> list[Render]:
    """Many voices in one batched rollout. Voices sharing a model roll together, at any mix of pitches, sample
    rates and bow curves. A voice whose picked model (no `model` given) leaves its trained states is played again by
    the next model that covers it (a tile's box of bows is wider than the states it learnt at its edges); one with no
    other model, or with the model given, is finished with the FDM (fallback 'fdm') or stops the render
    (DomainError). _models / _labels: the models left and the voices' numbers, for that second pass."""
    t_setup = time.perf_counter()
    # load each model file once: the voices must share model objects to be grouped into one rollout
    model = None if model is None else as_model(model)
    models = (available_models() if _models is None else _models) if model is None else None
    labels = list(range(1, len(scenes) + 1)) if _labels is None else _labels
    sounding = [None] * len(scenes) if sounding is None else list(sounding)
    groups: dict = {}
    out: list = [None] * len(scenes)
    for i, sc in enumerate(scenes):
        if sc.pitch_varies:  # a pitch curve: per window its own sample spacing (the live engine's voice loop)
            from .curve import render_curve  # the bank and its arrays: only for a pitch curve
            m = resolve_model(sc, model, models, fallback)
            r = render_curve(sc, m)
            rest = models
            while model is None and r.method.fdm_fallback:  # it left the picked model's states: the next one plays
                rest = [x for x in rest if x is not m]
                nxt = covering_model(sc, rest)
                if nxt is None:
                    break
                r2 = render_curve(sc, nxt)
                r2.info.notes = [_handover_note("" if _single else f"voice {labels[i]}: ", m, FAILURES[FAIL_DOMAIN],
                                                r2)] + r2.info.notes
                m, r = nxt, r2
            out[i] = r
            continue
        if model is None and sc.varying:
            from .chain import chain_plan, render_chain  # a bow crossing from one box into another
            plan = chain_plan(sc, models)  # None where one model covers it (or none can)
            if plan is not None:
                def play(seg, m, lock=None):
                    return render_operator_batch([seg], model=m, fallback=fallback, _single=True, sounding=[lock])[0]
                try:
                    out[i] = render_chain(sc, plan, play, "" if _single else f"voice {labels[i]}: ", sounding[i])
                    continue
                except DomainError:  # a model that cannot take the state it is handed: with --fallback fdm, the FDM
                    if fallback != "fdm":  # ends the note
                        raise
        m = resolve_model(sc, model, models, fallback)
        groups.setdefault(id(m), (m, []))[1].append(i)
    for m, idx in groups.values():
        checked = _physics_notes(m) + (unreadable_notes() if model is None else [])
        op = numpy_operator(m)
        t0 = time.perf_counter()
        # a note's first samples near its bow's rest point: the exact flow there (onset.py); the operator rolls out
        # the rest of the note from where it leaves (None: the whole note stayed there)
        pre, base = {}, {}
        win = {i: voice_window(m, scenes[i], sounding[i]) for i in idx}
        for i in idx:
            sc = scenes[i]
            ro = None if needs_whole_windows(m.domain, sc.beta_range[1]) else rest_onset(
                sc, m, op.samples_per_window(sc.dtau, win[i]))
            if ro is None:
                continue
            h, qr, pr, qh, ph = ro
            n = sc.n_samples
            if n - h < 2:  # a note too short (or too quiet) to leave: its last sample the state there
                qr, pr, h = np.append(qr, [qh] * (n - h)), np.append(pr, [ph] * (n - h)), n
            pre[i] = (h, qr, pr)
            base[i] = None if h == n else sc.after(h / sc.sample_rate, duration=(n - h) / sc.sample_rate, q0=qh,
                                                   p0=ph)
        t_rest = time.perf_counter() - t0
        idx_all, idx = idx, [i for i in idx if base.get(i, scenes[i]) is not None]
        rs = [base.get(i, scenes[i]) for i in idx]  # what the operator plays of each voice
        wins = [win[i] for i in idx]
        # each voice on the grid its model needs (grid.py: whole windows for stick-slip models), and back
        grids = [whole_window_scene(sc, op.samples_per_window(sc.dtau, w))
                 if needs_whole_windows(m.domain, sc.beta_range[1]) else (sc, 1) for sc, w in zip(rs, wins)]
        group = [g for g, _ in grids]
        x0 = np.array([[sc.q0, sc.p0] for sc in group]).reshape(-1, 2)
        dtau = np.array([sc.dtau for sc in group])
        wtau = np.array([op.window if w is None else w for w in wins])
        par, bows, leave = _voice_bows(m, group, wins) if group else (None, [], [])
        loop = "core"
        # the weights converted and the trunk features at these sample offsets, so that `seconds` measures the
        # rollout itself (start-up: info.setup_seconds)
        if group:
            prepare(m, dtau, wtau)
        t0 = time.perf_counter() - t_rest
        q, p, fail = [None] * len(group), [None] * len(group), [None] * len(group)
        for rows in length_buckets([g.n_samples for g in group]):
            qb, pb, fb = rollout_states(m, x0[rows], max(group[r].n_samples for r in rows), dtau[rows], loop=loop,
                                        params=par[rows], window=wtau[rows])
            for k, r in enumerate(rows):
                q[r], p[r], fail[r] = qb[k], pb[k], fb[k]
        voices = []  # per voice: q, p on the output grid, its stop [sample, code(, what)] there
        for row, (g, ratio) in enumerate(grids):
            stop = list(fail[row])
            bx = _box_exit(m, g, q[row][:g.n_samples], p[row][:g.n_samples], wins[row])
            if bx is not None and (stop[0] < 0 or bx < stop[0]):
                stop = [bx, FAIL_DOMAIN]
            lv = leave[row]
            if lv is not None and (stop[0] < 0 or lv[0] < stop[0]):
                stop = [lv[0], FAIL_BOW, lv[1]]
            ns = rs[row].n_samples
            if ratio == 1:
                qv, pv = q[row][:ns], p[row][:ns]
            else:
                if stop[0] >= 0:  # the grid's samples from the stop on are not the model's: the filter must not see them
                    q[row][stop[0]:] = p[row][stop[0]:] = np.nan
                qv, pv = to_output_in_place([q[row][:g.n_samples], p[row][:g.n_samples]], ratio, ns)
                stop[0] = from_grid(stop[0], ratio)
            if stop[0] >= 0:
                qv[stop[0]:] = np.nan
                pv[stop[0]:] = np.nan
            voices.append((qv, pv, stop))
        ctrl_of = {i: functools.partial(_applied, rs[row], grids[row], op, bows[row], leave[row], wins[row])
                   for row, i in enumerate(idx)}
        played = dict(zip(idx, voices))
        voices = []
        for i in idx_all:  # the flow at rest's samples before the operator's
            if i not in pre:
                voices.append(played[i])
                continue
            h, qr, pr = pre[i]
            qv, pv, stop = played.get(i, (np.zeros(0, np.float32), np.zeros(0, np.float32), [-1, 0]))
            stop = [stop[0] + h if stop[0] >= 0 else stop[0], *stop[1:]]
            voices.append((np.concatenate([qr.astype(np.float32), qv]), np.concatenate([pr.astype(np.float32), pv]),
                           stop))
            ctrl_of[i] = functools.partial(_applied_after_rest, scenes[i], m, h, ctrl_of.get(i), win[i])
        idx = idx_all
        landed = {}
        for row, i in enumerate(idx):  # a held note that sat at its rest point where the physics grows it
            mute = None if voices[row][2][0] >= 0 else mute_from(scenes[i], voices[row][1])
            if mute is not None:
                voices[row] = (*voices[row][:2], [mute, FAIL_MUTE])
            elif voices[row][2][0] < 0:  # or one that hums where the physics damps it
                landed[i] = ring_down(scenes[i], *voices[row][:2])
        again: list[int] = []
        if model is None:  # a voice that left the picked model's states: the next covering model plays it
            rest = [x for x in models if x is not m]
            again = [row for row, (i, (_, _, stop)) in enumerate(zip(idx, voices))
                     if stop[0] >= 0 and stop[1] != FAIL_BOW and covering_model(scenes[i], rest) is not None]
            if again:
                redo = render_operator_batch([scenes[idx[r]] for r in again], fallback=fallback, _single=_single,
                                             _models=rest, _labels=[labels[idx[r]] for r in again],
                                             sounding=[sounding[idx[r]] for r in again])
                for r, rr in zip(again, redo):
                    stop = voices[r][2]
                    why = f"{FAILURES[stop[1]]} at t = {stop[0] / scenes[idx[r]].sample_rate:.4f} s"
                    rr.info.notes = [_handover_note("" if _single else f"voice {labels[idx[r]]}: ", m, why, rr)
                                     ] + rr.info.notes
                    out[idx[r]] = rr
        notes = {i: _finish(scenes[i], qv, pv, stop, fallback, voice="" if _single else f"voice {labels[i]}: ")
                 + checked for row, (i, (qv, pv, stop)) in enumerate(zip(idx, voices)) if row not in again}
        secs = (time.perf_counter() - t0) / len(idx)
        for row, i in enumerate(idx):
            if row in again:
                continue
            sc = scenes[i]
            qv, pv, _ = voices[row]
            info = RenderInfo(model_id=m.id, model_path=str(m.path) if m.path else None, notes=notes[i], loop=loop,
                              setup_seconds=t0 - t_setup, batched=None if _single else len(idx))
            if m.domain.is_range:  # a range model is not equally good everywhere in its box: say how good
                v = m.meta.validation or {}
                info.range_validation = {k: v.get(k) for k in ("nmse", "nmse_max", "grid", "harm_db_median",
                                                               "cents_abs_max", "seconds", "ref_oversample",
                                                               "speaking", "resting", "silent_sounding")}
            if i in pre:
                info.rest_flow = pre[i][0] / sc.sample_rate
            if landed.get(i) is not None:  # a silent note, said: the physics rests there
                info.ring_down = landed[i] / sc.sample_rate
                vb = float(sc.vb_at(info.ring_down))
                info.notes = [*info.notes, f"note: {'' if _single else f'voice {labels[i]}: '}the bow damps the "
                              f"mass (v_B {vb:g} at or below 1/sqrt(2a) = {physics.vb_stop(sc.a):.4g}): the note "
                              f"rests, by the flow at rest from t = {info.ring_down:.4f} s"]
            if win[i] is not None:  # locked: how many windows a sounding period
                info.windows = round(2 * math.pi * sc.f0 / sounding[i] / win[i])
            # constant controls: the scene's own (Render's lazy default) are what ran
            ctrl = LazyControls(ctrl_of[i]) if sc.varying else None
            out[i] = Render(sc, None, qv, pv,
                            method=Played("operator", fdm_fallback=len(notes[i]) > len(checked)), seconds=secs,
                            info=info, **({"controls": ctrl} if ctrl is not None else {}))
    return out
