"""A scene whose pitch follows a curve, played by the operator window by window (each window at its own sample
spacing): one slot of a `bank.VoiceBank`, the code `bowsynth play` runs for pitch bend and vibrato."""

from __future__ import annotations

import math
import time

import numpy as np

from . import voices as V
from .bank import CURVE_POINTS, VoiceBank


def render_curve(scene, model):
    """The operator's render of a scene whose f0 follows a curve (vibrato, glissando, bend): one slot of the live
    engine, per window the window's own sample spacing (f0 at its middle), basis and end-state offsets, the same
    code `play` runs for pitch bend and CC1. F_B / w and v_B must hold (a MIDI note's bow, a score note's beta):
    else a SceneError says to render with the FDM. A window that leaves the model's states hands over to the FDM
    (following the curve) as a live note does; info['notes'] says so."""
    from ...controls import Curve, breakpoints
    from ...errors import DomainError, SceneError
    from ...render import Played, Render, RenderInfo
    from ..fdm import check_oversample
    from .choose import as_model
    from .grid import needs_whole_windows

    t_b = np.union1d(breakpoints(scene.fb)[0], scene.f0.times)
    betas = scene.fb_at(t_b) / (2.0 * math.pi * scene.f0_at(t_b))
    if isinstance(scene.vb, Curve) or np.ptp(betas) > 1e-9 * betas.max():
        raise SceneError("the operator plays a pitch curve with F_B / w and v_B held (a bow force growing with the "
                         "pitch, beta = ...); render this scene with --method fdm")
    if len(scene.f0.points) > CURVE_POINTS:
        raise SceneError(f"a pitch curve for the operator holds at most {CURVE_POINTS} breakpoints, this one "
                         f"{len(scene.f0.points)}")
    m = as_model(model)
    if needs_whole_windows(m.domain, float(betas.max())):
        raise DomainError(f"model {m.path or m.meta.name} plays stick-slip, which the operator computes on whole "
                          f"windows (a fixed pitch per note); under a pitch curve it does not yet: render with "
                          f"--method fdm")
    beta, vb = float(betas[0]), float(scene.vb)
    if not (m.domain.box_contains(beta, vb) and math.isclose(m.domain.a, scene.a, rel_tol=1e-9)):
        raise DomainError(f"model {m.path or m.meta.name} does not play F_B / w {beta:.4g}, v_B {vb:g}, a "
                          f"{scene.a:g}; render with --method fdm")
    sr = scene.sample_rate
    bank = VoiceBank(sr, 4096, 1, "operator", m, scene.f0.lo)
    f0 = float(scene.f0_at(0.0))
    bank.start_slot(0, f0, beta, vb, scene.a)
    bank.fdm[1][0, 1] = stride = check_oversample(scene, 1, warn=False)  # the slot's FDM (a hand-over) as render_fdm
    bank.fdm[0][0, 3] = 1.0 / (sr * stride)
    bank.bow_inputs(0, beta, vb)
    if not bank.start_operator(0, f0):
        raise DomainError(f"the model's window holds no sample at f0 {f0:g} Hz, {sr} Hz")
    pm, pp, pt, pv, npt = bank.pit[:5]
    pm[0], npt[0] = V.CURVE, len(scene.f0.points)
    pt[0, :npt[0]], pv[0, :npt[0]] = scene.f0.times, scene.f0.values
    bank.ops[0][0] = (scene.q0, scene.p0)
    bank.start_rest(0, beta, vb, scene.a, f0)  # a note near its bow's rest point starts with the flow there
    bank.pit[6][0] = -1.0  # the first window builds its own basis at its own spacing
    bank.end[0] = scene.n_samples
    n = scene.n_samples
    q, p = np.zeros(n), np.zeros(n)
    t0 = time.perf_counter()
    for a in range(0, n, bank.block):
        k = min(bank.block, n - a)
        bank.render(q[a:a + k], 0, k, 1.0, outp=p[a:a + k])
    secs = time.perf_counter() - t0
    notes = ["note: the rollout left the model's trained states; finished with the FDM from there"] \
        if bank.why[0] == V.WHY_FALLBACK else []
    return Render(scene, None, q.astype(np.float32), p.astype(np.float32),
                  method=Played("operator", fdm_fallback=bool(notes)), seconds=secs,
                  info=RenderInfo(model_id=m.id, model_path=str(m.path) if m.path else None, notes=notes,
                                  loop="per-window pitch"))
