"""Which model plays a scene: the registry of model files (./models, then the shipped ones, read once per change),
the covering model for a scene, and what to say when none covers it."""

from __future__ import annotations

import math
import os
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import numpy as np

from ... import physics
from ...controls import Curve
from ...errors import DomainError, ModelFileError
from ...scene import Scene
from .basis import numpy_operator
from .domain import span_text
from .modelfile import OperatorModel, grid_rests, is_finite, load_model
from .rollout import scene_bows
from .windows import window_bounds
from ... import shipped

SHIPPED_DIR = shipped("models")


def model_dirs() -> list[Path]:
    dirs = [Path.cwd() / "models", SHIPPED_DIR]
    out = []
    for d in dirs:
        try:
            if d.is_dir() and d.resolve() not in [o.resolve() for o in out]:
                out.append(d)
        except OSError:  # a folder this user may not search (a working directory under another's): none to read
            continue
    return out


def model_path(name) -> Path:
    """A model file given as a path, or by its name in ./models or the shipped models (`soft-range`): what
    `--model` and `train --from` take."""
    path = Path(name)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    for d in model_dirs():
        if (d / f"{name}.safetensors").is_file():
            return d / f"{name}.safetensors"
    names = sorted({f.stem for d in model_dirs() for f in d.glob("*.safetensors")})
    raise ModelFileError(f"model {name} not found: no such file, and no model of that name in ./models or the "
                         f"shipped models ({', '.join(names) or 'none'})")


def model_ref(path) -> str:
    """What names a model file to `--model` (model_path's inverse): a shipped model's name, which any install finds
    among its own shipped models (a cluster's node, a score's reader), else the file's path."""
    path = Path(path)
    return path.stem if path.parent.resolve() == SHIPPED_DIR.resolve() else str(path)


def as_model(model) -> OperatorModel:
    """An OperatorModel as given, or read from a file path or a model's name (model_path)."""
    return model if isinstance(model, OperatorModel) else load_model(model_path(model))


# Model files read in this process, by file identity (device, inode: a link and its target share one entry): (size,
# mtime_ns) when read, and the model or why it failed to load. A file is read again only when its size or
# modification time changes, so `render_operator(scene)` with no model costs a directory listing, not a load per call
# (measured ~110-160 ms per call with torch before). A score asks for the covering model several times a note (its
# tuning, its release, its coverage): the listing's own stats (os.scandir) keep each lookup to ~0.1 ms.
_SCANNED: dict = {}
# One listing for the whole of a render (one_listing): a render of one note asked four times (its pick, its windows'
# pick, the renderer's, the skipped files' notes), 0.4 ms each, a third of a 5 s note's render at 1000x real time.
_LISTING: ContextVar[list | None] = ContextVar("bowsynth_model_listing", default=None)


@contextmanager
def one_listing():
    """Within it every lookup reads the model directories as they were on entry (nested: the outermost listing)."""
    if _LISTING.get() is not None:
        yield
        return
    token = _LISTING.set(_scan())
    try:
        yield
    finally:
        _LISTING.reset(token)


def scan_models() -> list[tuple[Path, OperatorModel | None, str | None]]:
    """Every model file in ./models and the shipped ones: (path, model, None) or (path, None, why it is unreadable).
    Models are shared by all callers in this process: do not modify them."""
    listing = _LISTING.get()
    return _scan() if listing is None else listing


def _scan() -> list[tuple[Path, OperatorModel | None, str | None]]:
    found = []
    for d in model_dirs():
        try:
            with os.scandir(d) as it:
                entries = sorted((e for e in it if e.name.endswith(".safetensors")
                                  and not e.name.endswith(".ckpt.safetensors")), key=lambda e: e.name)
        except OSError:
            continue
        for e in entries:
            try:
                st = e.stat()
            except OSError:
                continue
            key, stamp = (st.st_dev, st.st_ino), (st.st_size, st.st_mtime_ns, e.path)
            hit = _SCANNED.get(key)
            if hit is None or hit[0] != stamp:
                p = Path(e.path)  # built on a change only: a Path per file per lookup was most of a lookup's time
                try:
                    hit = (stamp, p, load_model(p), None)
                except ModelFileError as e_:
                    hit = (stamp, p, None, str(e_))
                _SCANNED[key] = hit
            found.append(hit[1:])
    return found


def unreadable_notes() -> list[str]:
    """One line per model file the default lookup skipped because it cannot be used (damaged, foreign, forged)."""
    return [f"note: skipped {p}: {why.replace(str(p), p.name)}" for p, m, why in scan_models() if m is None]


def available_models() -> list[OperatorModel]:
    """The readable models (./models first, then the shipped ones), including those whose validation failed."""
    return [m for _, m, _ in scan_models() if m is not None]


def train_hint(scene: Scene) -> str:
    """The `bowsynth train` command whose model would cover the scene (a range for a scene whose bow moves)."""
    from ...controls import bounds

    def arg(v):
        lo, hi = bounds(v)
        return f"{lo:g}" if lo == hi else f"{lo:g}:{hi:g}"
    return (f"bowsynth train --fb {arg(scene.fb)} --f0 {arg(scene.f0)} --vb {arg(scene.vb)} --a {scene.a:g}"
            + (f" --q0 {scene.q0:g} --p0 {scene.p0:g}" if scene.q0 or scene.p0 else ""))


def first_bow_outside(model: OperatorModel, scene: Scene) -> tuple[float, str] | None:
    """Where the scene's bow first leaves the model's range, in the windows the operator would play it: (time in s,
    'F_B = ... at t = ...' naming the parameter and value), or None if it never does."""
    spw = numpy_operator(model).samples_per_window(scene.dtau)
    out = bow_exit(model, scene, spw, scene_bows(scene, spw))
    return None if out is None else (out[1] / scene.sample_rate, out[2])


def bow_exit(model: OperatorModel, scene: Scene, spw: float, bows: np.ndarray) -> tuple[int, int, str] | None:
    """The first window whose bow (of `bows`, scene_bows) is outside the model's range: (window, its first sample,
    what left and when), or None."""
    d = model.domain
    bad = np.flatnonzero(~d.box_contains(bows[:, 0], bows[:, 1]))
    if not bad.size:
        return None
    w = int(bad[0])
    start = int(window_bounds(spw, scene.n_samples)[0][w])
    t = start / scene.sample_rate
    beta, vb = bows[w]
    v_in = d.vb if d.box is None else min(max(vb, d.box[2]), d.box[3])  # v_B moved inside: does beta alone leave?
    if not d.box_contains(beta, v_in):
        return w, start, f"F_B = {beta * scene.omega:.4g} (F_B / w {beta:.4g}) at t = {t:.3f} s"
    return w, start, f"v_B = {vb:.4g} at t = {t:.3f} s"


# A range model is weakest at the edges of its box (fewer trained bows beyond them): where a scene's bows lie within
# this share of a box's span from its edge and another covering model has them deeper, that one plays. Measured
# there: the 103 Hz held bow F_B / w 0.0389, v_B 0.239 lies 1 % inside velocity-soft's box (1.7 dB, 0.45 cents
# from the truth) and 24 % inside soft-corner's (0.02 dB, 0.04 cents).
EDGE = 0.1


def bow_key(scene: Scene) -> tuple:
    """What decides which models cover a scene and how deep (Domain.mismatch, edge_depth): its bows' spans, whether
    v_B moves, a, the start state and the window's samples (f0_max, rate). Not its length or its pitch otherwise."""
    return (scene.beta_range, scene.vb_range, isinstance(scene.vb, Curve), scene.a, scene.q0, scene.p0,
            scene.f0_max, scene.sample_rate)


# covering_model's picks in this process, by the models looked among (the objects: a key holds them, so an id is
# never reused), which of them passed their validation, and the bow_key. A score asks several times a note (its
# tuning, its release, its lock, its batch) with a new Scene each time: 1032 asks over 19 models for a 172-note
# chorale, 0.33 s of its 2.6 s profiled.
_PICKS: dict = {}
MAX_PICKS = 4096


def covering_model(scene: Scene, models: list[OperatorModel] | None = None) -> OperatorModel | None:
    """find_model's pick, or None where it would raise (without composing the message: a score asks this of every
    note's release, most of which no model covers)."""
    pool = tuple(available_models() if models is None else models)
    ok = tuple(m.failure is None for m in pool)  # a trainer's model in memory is validated after it is made
    key = (pool, ok, bow_key(scene))
    if key in _PICKS:
        return _PICKS[key]
    good = [m for m, fine in zip(pool, ok) if fine and m.covers(scene)]
    b, v = scene.beta_range, scene.vb_range
    if v[1] < physics.vb_stop(scene.a):  # every bow damps the mass: the truth rests, as the resting boxes' models did
        good = [m for m in good if rests_throughout(m)] or good
    pick = min(good, key=lambda m: preference(m, m.domain.edge_depth(b, v))) if good else None
    if len(_PICKS) >= MAX_PICKS:
        _PICKS.clear()
    _PICKS[key] = pick
    return pick


def rests_throughout(m: OperatorModel) -> bool:
    """Whether a model was validated to rest at every grid bow of its box (training.selection.validate_range: the bow
    damps the mass at each, and it rests there). Where a scene's bows all damp the mass, such a model plays before
    any other that covers them, however deep: a tile trained for bow stops plays held heavy bows just below vb_stop
    as notes (p RMS 0.22 at F_B / w 1.3-1.65, v_B 0.068-0.07) where the truth rests, bows that lie at the top edge of
    a resting tile's box and deep in its own."""
    return grid_rests(m.meta.validation or {})


def preference(m: OperatorModel, depth: float) -> tuple:
    """The order in which models that cover a bow are picked (lowest first), given how deep the bow lies in each one's
    box (Domain.edge_depth): those that have it away from their edges (EDGE) first, then the most specialised (a
    point model, then the smallest box), then the best validation. Among models that all have the bow near
    their edges, the deepest first: there the edge, not the box's size, sets the error (F_B / w 0.431, v_B
    0.08 lies 5.7 % deep in loud-stops, the smaller box, which played it 9.2 dB and 28 cents off, and 8.1 % deep in
    slow-bow, which plays it 0.035 dB and 3.9 cents off). min() over it keeps the first of equals (./models before
    the shipped)."""
    shallow = depth < EDGE
    return shallow, -depth if shallow else m.domain.bow_extent, validation_rank(m)


def validation_rank(m: OperatorModel) -> tuple:
    """How two models of the same bows compare at validation, lowest first: NMSE(p) from rest. A point model plays
    free windows (music.engine_tuning.auto_lock), the windows its validation rolled: at the paper's F_B 1000 scene
    paper-fb1000-half (1.9e-5) plays free windows 0.017 dB and 0.002 cents from the truth, its stick capture 1.8 % of
    the p range off; paper-fb1000-knee in free windows 0.11 dB, 0.13 cents, 10 % (locked to the physics' period its
    capture is within 0.6 %, but the lock's pull-in puts its NMSE over 1 s at 1.8e-2, over the paper's 1e-2). A box
    where every grid bow rests has no NMSE on record: last among equals."""
    v = m.meta.validation or {}

    def recorded(key):  # inf for one missing or not a finite number: an edited file's null or text must not break it
        x = v.get(key)
        return float(x) if is_finite(x) else math.inf
    return (recorded("nmse"),)


def find_model(scene: Scene, models: list[OperatorModel] | None = None) -> OperatorModel:
    """The most specialised validated model (a point model, else the smallest box of bows: Domain.bow_extent; then
    the best validation: validation_rank; ./models before the shipped ones on a tie) among those
    (found, or the given list) that cover the scene. A model whose validation failed is never picked here (see
    model.validation_failure): pass it explicitly to use it. Otherwise a DomainError says which models come nearest
    and how to train one that covers the scene."""
    if models is None:
        models = available_models()
    pick = covering_model(scene, models)
    if pick is not None:
        return pick
    covering = [m for m in models if m.covers(scene)]
    if covering:
        bad = "; ".join(f"{m.path or m.meta.name} ({m.failure})" for m in covering)
        raise DomainError(f"the models that cover this scene failed their validation: {bad}. Pass one with --model "
                          f"to use it anyway, train longer with `{train_hint(scene)} --minutes 10`, or render with "
                          f"--method fdm")

    (blo, bhi), (vlo, vhi) = scene.beta_range, scene.vb_range

    def dist(m):
        d = m.domain
        b0, b1, v0, v1 = d.box if d.box else (d.beta, d.beta, d.vb, d.vb)
        db = max(0.0, math.log(max(b0, 1e-9) / max(blo, 1e-9)), math.log(max(bhi, 1e-9) / max(b1, 1e-9)))
        return db + max(0.0, v0 - vlo, vhi - v1) + abs(math.log(scene.a / d.a))
    near = sorted(models, key=dist)[:3]

    def why(m):
        out = m.domain.mismatch(scene)
        where = first_bow_outside(m, scene) if m.domain.is_range else None
        if where:
            out = [f"{where[1]} leaves its {m.domain.describe_bows()}"] + [
                o for o in out if not o.startswith(("F_B", "v_B"))]
        return ", ".join(out)
    lines = "; ".join(f"{m.path.name if m.path else m.meta.name} ({why(m)})" for m in near) or "none found"
    bow = (f"F_B / w = {span_text(blo, bhi)}, v_B = {span_text(vlo, vhi)}")
    raise DomainError(f"no model covers this scene ({bow}, a = {scene.a:g}); nearest: {lines}. Train one with "
                      f"`{train_hint(scene)}`, or render with --method fdm (or --fallback fdm)")


def partial_model(scene: Scene, models: list[OperatorModel] | None = None):
    """For --fallback fdm when no model covers the whole scene: the validated model that plays its opening longest
    (the start state and first bow inside, the bow leaving later), and the time it leaves; or None."""
    if models is None:
        models = available_models()
    best = None
    for m in models:
        if m.failure is not None or not m.domain.is_range or not m.domain.contains(scene.q0, scene.p0):
            continue
        if not math.isclose(scene.a, m.domain.a, rel_tol=1e-6):
            continue
        where = first_bow_outside(m, scene)
        if where and where[0] > 0 and (best is None or where[0] > best[1]):
            best = (m, where[0])
    return best
