"""A note's first samples near its bow's rest point: the exact flow linearised there (physics.rest_flow), the
operator taking over where the state leaves the radius.

Why: a note from rest grows from its bow's rest point by exp(-d tau / 2); at a light, slow bow (d small) that takes
0.2-2 s, and over it the network's small absolute errors near rest, compounded window after window, set when the note
speaks (a range model's onsets 12-700 ms off at the slow corner, docs/BENCHMARKS.md "The flow at rest"). There the
linearised flow is exact up to the friction's curvature, which the radius bounds. The loop is the compiled core's
rest_run, the one the live voices run (voices.cpp, REST mode), so the offline and live notes agree.
"""

from __future__ import annotations

import math

import numpy as np

from ... import compiled as core
from ... import physics
from ...controls import Curve
from ...scene import Scene
from .rollout import scene_bows
from .windows import window_bounds

CHUNK = 32  # windows whose rows are built at a time when the bow moves (a note leaves the radius within ~0.2-2 s)


def _held_flow(d: float, qs: float, r: float, dtau: float, q: float, p: float, oq, op):
    """The flow at rest of one held bow (d, q_s, radius r) from (q, p), a step of dtau a sample, into oq and op while
    the state stays within r: (samples played, q, p at the next), by the core's rest_run with one row of
    coefficients, the loop of the live voices' REST mode."""
    c = np.zeros((1, 8))
    core.load().rest_coefficients(np.array([d]), np.array([qs]), np.array([dtau]), c)
    c[0, 7] = r
    return core.load().rest_run(q, p, c, len(oq), oq, op)


def uses_rest_flow(m) -> bool:
    """Range models start a note with the flow at rest. A point model learnt its own bow's trajectory from rest
    (paper-fb10: onset errors of microseconds; scratch-g2 carries the rest flow inside its network), so its notes
    are left to it."""
    return m.domain.is_range


def rest_onset(sc: Scene, m, spw: float):
    """The scene's first samples by the flow at rest, while its state stays within the radius of each window's bow
    (the bows the operator would play, scene_bows): (h, q, p, qh, ph) with q, p its h samples (float64) and (qh, ph)
    the state at sample h, where the operator goes on (h = n_samples: the whole note); or None where it does not
    apply (a point model, a start away from the rest point)."""
    if not uses_rest_flow(m) or sc.pitch_varies:
        return None
    # the first window's middle (scene_bows' bow there) decides, before the bows of every window are built: most
    # notes start far from rest
    t = 0.5 * window_bounds(spw, min(sc.n_samples, int(2 * spw) + 2))[1][0] / sc.sample_rate
    flow = physics.rest_flow(float(sc.fb_at(t)) / sc.omega, float(sc.vb_at(t)), sc.a, sc.q0, sc.p0)
    if flow is None:
        return None
    bows = scene_bows(sc, spw)
    n = sc.n_samples
    oq, op = np.empty(n), np.empty(n)
    lib = core.load()
    q, p = float(sc.q0), float(sc.p0)
    if np.ptp(bows[:, 0]) == 0 and np.ptp(bows[:, 1]) == 0:  # one bow throughout: one row, as a live note's
        h, q, p = _held_flow(*flow, sc.dtau, q, p, oq, op)
        return h, oq[:h], op[:h], q, p
    starts, ends = window_bounds(spw, n)
    ends = np.minimum(ends, n)
    W = min(len(starts), len(bows))
    h = 0
    for w0 in range(0, W, CHUNK):
        w1 = min(w0 + CHUNK, W)
        s0, s1 = int(starts[w0]), int(ends[w1 - 1])
        # each sample's step at the bow of its own time (a bow held per window would move the rest point in steps, one
        # a period, all at the same phase: they pumped the swing, the note spoke 14 ms early of 254); the radius per
        # window (a tolerance, not a rate)
        t = (np.arange(s0, s1) + 0.5) / sc.sample_rate
        d, qs = physics.rest_linearisation(sc.fb_at(t) / sc.omega, sc.vb_at(t), sc.a)
        r = np.repeat([physics.rest_radius(float(x), float(sc.a)) for x in bows[w0:w1, 1]],
                      (ends[w0:w1] - starts[w0:w1]).astype(np.int64))
        ok = np.isfinite(d)
        per = np.zeros((s1 - s0, 8))
        lib.rest_coefficients(np.where(ok, d, 0.0), qs, np.full(s1 - s0, sc.dtau), per)
        per[:, 7] = np.where(ok, r, -1.0)  # no linearisation: the state is outside at once
        k, q, p = lib.rest_run(q, p, per, s1 - s0, oq[s0:], op[s0:])
        h = s0 + k
        if k < s1 - s0:
            break
    return h, oq[:h], op[:h], q, p


# A note must speak where the physics says it does. A stick-slip tile can play F_B / w 2, v_B 0.28 (the playing
# space's corner) from rest as a note that never speaks: p spanned 0.02 where the truth's spans 2.46, inside the
# trained states, so nothing else stops it. About the rest point a held bow above vb_stop grows any motion at
# physics.onset_rate; from the note's initial offset it reaches the scale v_B - vb_stop by t_speak. Measured
# (benchmarks/mute_check.py: bench map's 160 bows at 110 and 440 Hz, 2 s from rest, the x8 FDM): the truth's p spans
# a quarter of that scale before t_speak at every bow, and wherever 1.5 t_speak falls inside the note its last four
# free periods span at least 1.5x the scale. So a held note whose p spans less than MUTE_FRACTION of the scale from
# MUTE_SAFETY t_speak to its end, at least MUTE_PERIODS free periods (a stick-slip cycle at F_B / w 2 is three), did
# not speak.
MUTE_FRACTION = 0.25
MUTE_SAFETY = 1.5
MUTE_PERIODS = 8


def speak_time(sc: Scene) -> float | None:
    """t_speak in tau: when the linearised growth about the rest point (physics.onset_rate) takes a held note from its
    initial offset to the scale v_B - vb_stop; None where the bow moves or the physics lets the mass rest."""
    if sc.varying or sc.pitch_varies:
        return None
    rate = physics.onset_rate(sc.beta, sc.vb, sc.a)
    scale = sc.vb - physics.vb_stop(sc.a)
    if not rate > 0 or not scale > 0:
        return None
    offset = max(float(np.hypot(sc.q0 - physics.rest_linearisation(sc.beta, sc.vb, sc.a)[1], sc.p0)), 1e-12)
    return float(physics.growth_tau(rate, offset, scale))


def settled_seconds(sc: Scene, after: float = 2.0, most: float = 30.0) -> float:
    """How long a held note from the scene's start must last to be `after` seconds past its onset: `after`, or where
    the physics takes more than a second to speak (speak_time) that time plus `after`, at most `most`. A light fast
    bow speaks late: F_B / w 0.02, v_B 0.28 after ~9.8 s at f0 100 (its half-RMS onset 8.2 s)."""
    t = speak_time(sc)
    speak = 0.0 if t is None else t / sc.omega
    return after if speak <= 1.0 else min(most, speak + after)


def mute_from(sc: Scene, p) -> int | None:
    """The sample from which a held note should have been sounding but was not (its p spans < MUTE_FRACTION of
    v_B - vb_stop from there to its end), or None: it sounds, the bow moves, or the physics lets it be silent."""
    t_speak = speak_time(sc)
    if t_speak is None:
        return None
    at = MUTE_SAFETY * t_speak / sc.dtau
    if not at < sc.n_samples:  # it speaks after the note ends (a force of 1e-309 never does in floats: inf)
        return None
    at = math.ceil(at)
    if sc.n_samples - at < MUTE_PERIODS * 2 * math.pi / sc.dtau:
        return None
    tail = np.asarray(p[at:])  # in its own dtype: a float64 copy of a 5 s note cost 0.1-0.5 ms of a 6 ms render
    lo, hi = float(tail.min()), float(tail.max())  # NaN propagates: a stopped voice is not called mute here
    scale = sc.vb - physics.vb_stop(sc.a)
    return at if math.isfinite(lo) and math.isfinite(hi) and hi - lo < MUTE_FRACTION * scale else None


# ring_down: the share of the width where the friction's slope stays positive over a swing (|p| < vb_stop - v_B)
# within which a bow held from the note's start, whose state never enters the linearised radius, plays the decay
DAMP_SHARE = 0.5
# Just below vb_stop that width vanishes (1e-4 at v_B 0.0706), yet the truth comes to rest from much further: from
# states vb_stop / 2 and vb_stop off its rest point, 8 phases each, at every one of 36 bows (F_B / w 0.05-2 x v_B
# 0-0.0707, x20 FDM). There heavy bows' models crept to rest and on past it into a full note (p RMS
# 0.11-0.27 where the truth rests), never entering the exact radius on the way. So a held bow's note whose state
# passes within BASIN_SHARE vb_stop of its rest point, and leaves again before it enters the exact radius (or never
# enters it), rings down from its closest approach on that pass, if the swing there is within BASIN_SWING vb_stop
# (0.007, a creep's last swing; a note plays at 0.05-0.6) or the flow at rest takes it below silence (physics.SILENT)
# by the note's last half. A light bow barely damped rings wider (F_B / w 0.05-0.2 at v_B 0.0703-0.0706 and 110 Hz:
# 0.01-0.03 off, d 0.008, its truth ringing on at 1e-4 to 2e-3), which the linear flow would decay too slowly: the
# operator plays it.
BASIN_SHARE = 0.5
BASIN_SWING = 0.1


def _basin_entry(sc: Scene, d: float, dist2, dphase: float) -> tuple[int | None, int]:
    """(k, end): the state's first pass within BASIN_SHARE vb_stop of the rest point ends at sample end (from the
    note's start: where it leaves, or the note's end), and k is its closest approach within a period of the entry if
    the swing there is within BASIN_SWING vb_stop or the flow at rest (decaying as exp(-d tau / 2)) takes it below
    physics.SILENT by the note's last half, else None. (None, 0) where the state never comes within."""
    stop = physics.vb_stop(float(sc.a))
    basin = BASIN_SHARE * stop
    near = dist2 <= basin * basin
    if not near.any():
        return None, 0
    k0 = int(np.argmax(near))
    out = np.flatnonzero(~near[k0:])
    end = k0 + (int(out[0]) if len(out) else len(near) - k0)
    k1 = min(end, k0 + max(1, math.ceil(2 * math.pi / dphase)))  # a period on: the pass, not a later hum
    k = k0 + int(np.argmin(dist2[k0:k1]))
    swing = math.sqrt(float(dist2[k]))
    left = (len(dist2) // 2 - k) * dphase  # tau from there to the note's last half, whose RMS says it sounds
    fine = swing <= BASIN_SWING * stop
    return (k if fine or swing * math.exp(-0.5 * d * max(left, 0.0)) <= physics.SILENT else None), end


def ring_down(sc: Scene, q, p) -> int | None:
    """A bow that damps the mass (below vb_stop: d > 0), held from some time to the note's end, plays from the first
    sample after that time whose state lies within the radius of its rest point the exact flow linearised there, in
    place in q and p. Inside the radius the swing can only shrink (d/dtau ((q - q_s)^2 + p^2) = -2 d p^2), so the
    note comes to rest as the physics does, where the operator left alone settled on a faint hum: bench map's held
    bows, p RMS 1e-4 to 3e-3 at 20 of its 36 silent cells; a bow stop to v_B 0, 6e-5 to 3e-4 after it where the truth
    decays to 1e-15 and below. A bow held from the note's start may ring down from further out (_basin_entry: the
    truth rests from anywhere within vb_stop of its rest point). Returns that sample, or None: the bow at the end
    drives the mass, or the state never came in."""
    # the last breakpoint of any curve: from there pitch, force and speed hold still
    hold = max([c.points[-1][0] for c in (sc.f0, sc.fb, sc.vb) if isinstance(c, Curve)], default=0.0)
    s0, n = max(0, math.ceil(hold * sc.sample_rate)), len(q)
    if s0 >= n:
        return None
    t_end = (n - 1) / sc.sample_rate
    w = physics.omega(float(sc.f0_at(t_end)))
    vb = float(sc.vb_at(t_end))
    d, qs = physics.rest_linearisation(float(sc.fb_at(t_end)) / w, vb, sc.a)
    if not d > 0:  # the bow drives the mass (every sounding note): no radius to look for
        return None
    r = physics.rest_radius(vb, float(sc.a))
    if not r > 0:
        return None
    with np.errstate(invalid="ignore"):
        dist2 = np.square(q[s0:] - qs) + np.square(p[s0:])
    inside = s0 + np.flatnonzero(dist2 <= r * r)
    if hold == 0.0:
        # the exact radius where the state reaches it on its first pass through the basin; the basin's closest
        # approach where it leaves before (a creep that went on into a note) or never comes that near
        k, end = _basin_entry(sc, d, dist2, w / sc.sample_rate)
        if k is not None and not (len(inside) and inside[0] < end):
            inside, r = np.array([k]), max(r, BASIN_SHARE * physics.vb_stop(float(sc.a)))
    if not len(inside) and hold == 0.0:
        # a bow held from the note's start: the physics rests (the truth from rest: p RMS ~1e-13 at every such bow
        # measured), and the swing shrinks wherever the friction's slope stays positive over it, |p| < vb_stop - v_B.
        # stick-halt settles 0.003-0.015 off its rest point there, humming (p RMS 3e-4 to 9e-4 at F_B / w 1.3-1.7,
        # v_B 0.04-0.06; the linearised radius is 0.002-0.006): the flow plays the decay from within DAMP_SHARE of
        # that width (its envelope, not exact, of a swing already that small)
        wide = DAMP_SHARE * (physics.vb_stop(float(sc.a)) - vb)
        inside = s0 + np.flatnonzero(dist2 <= wide * wide)
        r = max(r, wide)
    if not len(inside):
        return None
    k = int(inside[0])
    # played as a note's first samples are (rest_onset); inside the radius the state does not leave it
    oq, op = np.empty(n - k), np.empty(n - k)
    h = _held_flow(d, qs, r, w / sc.sample_rate, float(q[k]), float(p[k]), oq, op)[0]
    q[k:k + h], p[k:k + h] = oq[:h], op[:h]
    return k
