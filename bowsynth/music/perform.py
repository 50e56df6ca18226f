"""A piece performed: which model covers which notes, the sustains rendered by the chosen engine (batched), and the
releases played by the operator where a model reaches v_B = 0 (the sustain's own model, or another one handed the
sustain's state at the hold), else by the FDM from that state."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..controls import after
from ..errors import DomainError, UsageError
from ..render import Render
from ..scene import Scene
from .note import Note
from .score import ScoreError


def score_box(notes: list[Note]) -> dict:
    """The box of dimensionless physics the notes visit during their sustains (the release is the FDM's):
    {'beta': (lo, hi), 'vb': (lo, hi), 'a': (lo, hi), 'f0': (lo, hi), 'notes': n, 'gestures': n with curves}."""
    if not notes:
        raise ScoreError("no notes")
    sus = [n.sustain_scene() for n in notes]
    bl = [s.beta_range for s in sus]
    vl = [s.vb_range for s in sus]
    return {"beta": (min(b[0] for b in bl), max(b[1] for b in bl)), "vb": (min(v[0] for v in vl), max(v[1] for v in vl)),
            "a": (min(s.a for s in sus), max(s.a for s in sus)), "f0": (min(s.f0 for s in sus), max(s.f0 for s in sus)),
            "notes": len(notes), "gestures": sum(s.varying for s in sus)}


def uncovered(notes: list[Note], model=None) -> list[tuple[Note, str]]:
    """The notes no operator model can play (their sustain), each with the reason."""
    from ..engines.operator.chain import chain_plan
    from ..engines.operator.choose import available_models
    from ..engines.operator.engine import resolve_model

    models = None
    if model is None:
        models = available_models()
    else:
        from ..engines.operator.choose import as_model

        model = as_model(model)
    out = []
    for n in notes:
        sc = n.rollout_scene()
        try:
            resolve_model(sc, model, models)
        except DomainError:
            if model is None and chain_plan(sc, models) is not None:
                continue  # models in turn play its bow (engines/operator/chain.py)
            (blo, bhi), (vlo, vhi) = sc.beta_range, sc.vb_range
            b = f"{blo:.4g}" if blo == bhi else f"{blo:.4g}..{bhi:.4g}"
            v = f"{vlo:g}" if vlo == vhi else f"{vlo:g}..{vhi:g}"
            out.append((n, f"F_B / w = {b}, v_B = {v}, a = {sc.a:g}"))
    return out


def coverage_message(notes: list[Note], missing: list[tuple[Note, str]], source=None) -> str:
    box = score_box(notes)
    shown = "; ".join(f"{n.describe()} ({why})" for n, why in missing[:3])
    more = f"; and {len(missing) - 3} more" if len(missing) > 3 else ""
    train = f"bowsynth train --score {source}" if source else "bowsynth train"
    return (f"{len(missing)} of {len(notes)} notes fall outside every model's range: {shown}{more}. The piece spans "
            f"F_B / w {box['beta'][0]:.4g}..{box['beta'][1]:.4g}, v_B {box['vb'][0]:g}..{box['vb'][1]:g}, "
            f"a {box['a'][0]:g}..{box['a'][1]:g}: train a model that covers it with `{train}`, or render with "
            f"--method fdm (or --fallback fdm for these notes only)")


RELEASES = ("auto", "fdm")


def check_releases(releases: str) -> str:
    """Who plays the bow stops: 'auto' or 'fdm' (render_notes), else one line."""
    if releases not in RELEASES:
        raise UsageError(f"--releases must be {' or '.join(RELEASES)}, got {releases!r}")
    return releases


def render_notes(notes: list[Note], method: str = "operator", model=None, fallback: str = "none",
                 source=None, releases: str = "auto", windows: str | None = None) -> list[Render]:
    """_render_notes of the distinct notes, each repeat a copy of its first (a note's samples depend only on its
    scene, hold and release, not on when it starts: 79 distinct among a chorale's 172 notes)."""
    first: dict = {}
    which = [first.setdefault(same_note(n), i) for i, n in enumerate(notes)]
    if len(first) == len(notes):
        return _render_notes(notes, method, model, fallback, source, releases, windows)
    uniq = sorted(first.values())
    rs = dict(zip(uniq, _render_notes([notes[i] for i in uniq], method, model, fallback, source, releases, windows)))
    return [rs[i] if i == j else repeat(rs[j], notes[i]) for i, j in enumerate(which)]


def same_note(n: Note) -> tuple:
    """What a note's samples depend on."""
    return n.scene, n.hold, n.release


def repeat(r: Render, note: Note) -> Render:
    """A copy of r for another note with the same samples (its own arrays: a release is written in place)."""
    chain = None if r.info.chain is None else list(r.info.chain)
    info = dataclasses.replace(r.info, notes=list(r.info.notes), chain=chain)
    return Render(note.scene, r.t, r.q.copy(), r.p.copy(), r.method, 0.0, info, r.controls)


def _render_notes(notes: list[Note], method: str = "operator", model=None, fallback: str = "none",
                  source=None, releases: str = "auto", windows: str | None = None) -> list[Render]:
    """Render every note: with the FDM whole (it follows the curves), or with the operator in one batched rollout
    of the sustains, each bow stop then by a model that covers it (the sustain's own, whole; or one handed the
    sustain's state at the hold), else by the FDM from there. releases 'fdm': every bow stop by the FDM from the hold,
    as the live engine plays them (its voice loop has no operator bow stop yet), so that a live recording can be
    compared sample for sample. Notes no model covers are refused before anything renders (fallback 'fdm': rendered
    by the FDM instead, noted in info.notes). windows 'locked': each note's windows locked to the period its model
    sounds at with the note's held bow (`api.render`'s windows: the pitch it was tuned to sound at, where tuned with
    that model), 'free': the trained windows; None: engine_tuning.SCORE_WINDOWS."""
    from ..engines import Engine, Fallback, parse_choice, render

    engine = parse_choice(Engine, method, "--method")
    fb_mode = parse_choice(Fallback, fallback, "--fallback")
    check_releases(releases)
    if engine is Engine.fdm:
        return render([n.scene for n in notes], engine="fdm")
    missing = {id(n): why for n, why in uncovered(notes, model)}
    if missing and fb_mode is not Fallback.fdm:
        raise ScoreError(coverage_message(notes, [(n, missing[id(n)]) for n in notes if id(n) in missing], source))
    out: list = [None] * len(notes)
    op = [i for i, n in enumerate(notes) if id(n) not in missing]
    for i, n in enumerate(notes):
        if id(n) in missing:
            r = render(n.scene, engine="fdm")
            r.info.notes.append(f"no model covers it ({missing[id(n)]}): rendered by the FDM")
            out[i] = r
    # a note whose bow stop and tail its sustain's model covers too (a box reaching v_B = 0) is played whole by it
    from ..engines.operator.choose import available_models

    # one look at the model directories for all the notes; a bow stop is played by a model that covers it even where
    # the sustains' model is given
    pool = available_models()
    by_model = releases == "auto"
    whole = [i for i in op if by_model and notes[i].release > 0 and _plays_whole(notes[i], model, pool)]
    from .engine_tuning import SCORE_WINDOWS, check_windows, sounding_for

    windows = check_windows(windows, SCORE_WINDOWS)

    def hints(scenes, held=None):  # each note's lock: its model's own period at the bow it holds until its stop
        return sounding_for(scenes, windows, model, held=held)

    if whole:
        scenes = [notes[i].scene for i in whole]
        for i, r in zip(whole, render(scenes, engine="operator", model=model, fallback=fallback,
                                      sounding=hints(scenes, [notes[i].rollout_scene() for i in whole]))):
            r.info.release = "operator"
            out[i] = r
    part = [i for i in op if i not in set(whole)]
    if part:
        sustains = [notes[i].rollout_scene() for i in part]
        # the sustains are the held bows themselves
        rs = render(sustains, engine="operator", model=model, fallback=fallback, sounding=hints(sustains))
        # the other releases: by a model that covers the bow stop (picked among the same models); the FDM plays
        # those no model covers only when asked (--releases fdm, --fallback fdm)
        strict = by_model and fb_mode is not Fallback.fdm
        for i, r in zip(part, finish_releases([notes[i] for i in part], rs, models=pool if by_model else None,
                                              source=source if strict else False)):
            out[i] = r
    return out


def _plays_whole(note: Note, model=None, models=None) -> bool:
    """Does the model that would play the note's sustain (the one given, else the lookup's pick among `models`) cover
    the whole note, its bow stop and tail included? (Else the release is handed over at the hold: finish_releases.)"""
    from ..engines.operator.choose import as_model, covering_model

    m = covering_model(note.rollout_scene(), models) if model is None else as_model(model)
    return m is not None and m.covers(note.scene)


def _release_scene(note: Note, sus: Render) -> Scene:
    """The note after its sustain: v_B falls to 0 over the release, from the sustain's state at the hold."""
    sc, h = note.scene, note.hold_samples
    if sc.pitch_varies:  # the pitch (and a force that follows it) go on along their curves from the hold's sample
        t0 = h / sc.sample_rate
        f0, fb = after(sc.f0, t0), after(sc.fb, t0)
    else:
        f0, fb = sc.f0, float(sc.fb_at(note.hold))
    return Scene(f0=f0, fb=fb, vb=[[0.0, float(sc.vb_at(note.hold))], [note.release, 0.0]],
                 a=sc.a, duration=(sc.n_samples - h) / sc.sample_rate, sample_rate=sc.sample_rate,
                 q0=float(sus.q[h]), p0=float(sus.p[h]))


def finish_releases(notes: list[Note], sustains: list[Render], loop: str = "auto", models=None,
                    source=False) -> list[Render]:
    """Each note's release from its sustain's state at the hold, written over the sustain's samples from there on
    (`sustains` rendered from `Note.rollout_scene`, so they already span the whole note): by the operator where one of
    `models` (a list, e.g. `available_models()`; None: none) covers the release's bow stop, else by the FDM.

    Each release runs `render_fdm`'s compiled loop (src/core/fdm.cpp): same scheme, start and Newton iteration, in
    a few milliseconds (a chorale's 151 releases took 0.96 s in the numpy batch). loop: 'core' ('auto' is the same),
    or 'numpy': all releases of a sample rate and oversampling in one numpy batch (`fdm.fdm_batch`), the readable
    reference the tests hold the compiled loop to. source: not False (a score's file, or None), the FDM plays no
    release: one that no model covers is refused (ScoreError) naming the train command and --releases fdm."""
    from ..engines.fdm import check_oversample, fdm_batch, render_fdm

    if loop == "auto":
        loop = "core"
    if loop not in ("numpy", "core"):
        raise ValueError(f"loop must be auto, core or numpy, got {loop!r}")

    out = [None] * len(notes)
    groups: dict[tuple, list[int]] = {}
    scenes = {}
    for i, (n, sus) in enumerate(zip(notes, sustains)):
        if n.release <= 0:
            out[i] = Render(n.scene, sus.t, sus.q, sus.p, sus.method, sus.seconds, sus.info)
            continue
        if len(sus.q) != n.scene.n_samples:
            raise ValueError(f"{n.describe()}: the sustain has {len(sus.q)} samples, the note "
                             f"{n.scene.n_samples} (render Note.rollout_scene)")
        scenes[i] = rel = _release_scene(n, sus)
        os_ = check_oversample(rel, 1, warn=False)
        # a moving pitch: the compiled FDM, which follows w(t) (the numpy batch holds one w per note)
        groups.setdefault((rel.sample_rate, os_, rel.a, rel.pitch_varies), []).append(i)
    if models:
        _operator_releases(notes, sustains, scenes, groups, models, out)
    left = [i for idx in groups.values() for i in idx]
    if left and source is not False:
        shown = "; ".join(notes[i].describe() for i in left[:3]) + (f"; and {len(left) - 3} more" if len(left) > 3
                                                                      else "")
        train = f"bowsynth train --score {source}" if source else "bowsynth train"
        raise ScoreError(f"{len(left)} bow stop(s) fall outside every model's range: {shown}. Train a model that "
                         f"covers them with `{train}`, or play them with the FDM: --releases fdm (or --fallback fdm)")
    for (sr, os_, a, moving), idx in groups.items():
        rel = [scenes[i] for i in idx]
        if not rel:
            continue
        if loop == "core" or moving:
            for i, r in zip(idx, rel):
                f = render_fdm(r, os_)
                out[i] = _join_release(notes[i], sustains[i], f.q, f.p, f.seconds)
            continue
        vb0 = np.array([r.vb_at(0.0) for r in rel])
        span = np.array([notes[i].release for i in idx])
        k = 1.0 / (sr * os_)
        n_out = max(r.n_samples for r in rel)
        t0 = time.perf_counter()
        # the ramp as controls.Curve evaluates it (v0 + (v1 - v0) (t - t0) / (t1 - t0)), held at 0 after it
        q, p = fdm_batch([r.q0 for r in rel], [r.p0 for r in rel], n_out, os_, k, np.array([r.omega for r in rel]),
                         np.array([float(r.fb_at(0.0)) for r in rel]),
                         lambda t: np.where(t >= span, 0.0, vb0 + (0.0 - vb0) * t / span), a)
        secs = (time.perf_counter() - t0) / len(idx)
        for row, i in enumerate(idx):
            m = scenes[i].n_samples
            out[i] = _join_release(notes[i], sustains[i], q[row, :m], p[row, :m], secs)
    return out


def _operator_releases(notes, sustains, scenes, groups, models, out) -> None:
    """The releases some model covers, rolled out by it (batched per model) from the sustain's state at the hold;
    taken out of `groups` (left to the FDM). A release that leaves its model's states is finished by the FDM, and its
    method says so ("operator+fdm")."""
    from ..engines.operator.choose import covering_model
    from ..engines.operator.engine import render_operator_batch

    by_model: dict[int, tuple] = {}
    for key, idx in groups.items():
        keep = []
        for i in idx:
            m = None if scenes[i].pitch_varies else covering_model(scenes[i], models)
            if m is None:
                keep.append(i)
            else:
                by_model.setdefault(id(m), (m, []))[1].append(i)
        groups[key] = keep
    for m, idx in by_model.values():
        for i, r in zip(idx, render_operator_batch([scenes[i] for i in idx], model=m, fallback="fdm")):
            out[i] = _join_release(notes[i], sustains[i], r.q, r.p, r.seconds, by="operator", played=r.method)
            out[i].info.release_model = f"{r.info.model_id} ({r.info.model_path})"


def _join_release(n: Note, sus: Render, q: np.ndarray, p: np.ndarray, secs: float, by: str = "fdm",
                  played=None) -> Render:
    """The note: its sustain up to the hold, the release's samples written over the rest. by: who played the release
    (the FDM, or the operator with `played` its method: a release the FDM finished makes the note operator+fdm)."""
    h = n.hold_samples
    sus.q[h:] = q
    sus.p[h:] = p
    info = dataclasses.replace(sus.info, notes=list(sus.info.notes), release=by)
    if by == "fdm":
        method = sus.method.with_fdm_release()
    else:
        method = type(sus.method)(sus.method.engine, sus.method.oversample,
                                  sus.method.fdm_fallback or played.fdm_fallback, sus.method.fdm_release)
    return Render(n.scene, sus.t, sus.q, sus.p, method=method, seconds=sus.seconds + secs, info=info)
