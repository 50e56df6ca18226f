"""What the live engine works out before it activates: the bow of every velocity at neutral controllers and the f0
of every (velocity, note), tuned by `music.tuning.tune` exactly as `score` tunes a MIDI file's note (with the sounding
ratio of the engine that plays it: `music.engine_tuning.ratio_for_engine`), the physics' ratio over the bows CC2 /
CC11 reach (from the shipped map, `music.ratio_map`: no reference runs), and the model that plays the most of the
keyboard."""

from __future__ import annotations

import math

import numpy as np

from .. import physics
from ..errors import DomainError
from ..engines.operator.grid import needs_whole_windows
from ..music import midi as M
from ..music.notes import midi_to_hz
from ..music.ratio_map import physics_ratio
from ..music.tuning import SilentNoteError, tune
from ..scene import Scene

# the tuning grid for bows off the velocity table: F_B / w over the velocities' span (0.040..0.637) and a little
# more, v_B from where a note barely speaks to the fastest velocity's bow; 9 x 8 ratios, measured once (disk-cached)
GRID_BETA, GRID_VB, GRID_N = (0.03, 0.8), (0.1, 0.25), (9, 8)
DENSE = (512, 256)  # the spline through them, tabulated


class Tuning:
    """v_beta, v_vb (128,): each velocity's F_B / w and v_B at neutral controllers; f0 (128, 128): the oscillator f0
    of each (velocity, note), NaN where the bow does not speak; `grid_ratio(beta, vb)`: the sounding ratio of any
    other bow. ratio_for(scene): the engine's ratio function for a note's scene, or None for the truth's (score's
    `ratio_for`)."""

    def __init__(self, a: float, a4: float, sample_rate: int, ratio_for=None):
        self.v_beta = np.array([M.bow_beta(v) for v in range(128)])
        self.v_vb = np.array([M.bow_vb(v) for v in range(128)])
        self.f0 = np.full((128, 128), np.nan)

        def rf(hz, beta, vb):
            if ratio_for is None:
                return None
            return ratio_for(Scene(f0=hz, fb=beta * physics.omega(hz), vb=vb, a=a, sample_rate=sample_rate))
        for v in range(1, 128):
            beta, vb = float(self.v_beta[v]), float(self.v_vb[v])
            try:
                physics_ratio(beta, vb, a)
            except SilentNoteError:
                continue  # a velocity whose note does not speak stays NaN: its notes are dropped (`silent`)
            for n in range(12, 120):
                hz = midi_to_hz(n, a4)
                self.f0[v, n] = tune(hz, None, beta=beta, vb=vb, a=a, a4=a4, ratio=rf(hz, beta, vb),
                                     physics_ratio=physics_ratio).f0
        # the truth's ratios: smooth in the bow, so a 9 x 8 spline holds them to 0.01-0.22 cents. The operator's own
        # (what `score` tunes an operator note with) are not: its pitch error varies from bow to bow, and a spline
        # through 72 of them was 1-9 cents off between them; the truth's are 0.2-2.5 cents from them (docs/live.md)
        (b0, b1), (v0, v1) = GRID_BETA, GRID_VB
        logb = np.linspace(math.log(b0), math.log(b1), GRID_N[0])
        vbs = np.linspace(v0, v1, GRID_N[1])
        r = np.full(GRID_N, np.nan)
        for i, lb in enumerate(logb):
            for j, vb in enumerate(vbs):
                b = float(math.exp(lb))
                try:
                    r[i, j] = physics_ratio(b, float(vb), a).r
                except SilentNoteError:
                    pass
        # bicubic through the measured points (bilinear was 4-7 cents off between them; this 0.01-0.22), sampled
        # densely here so that the callback interpolates bilinearly in a table (no scipy call there)
        from scipy.interpolate import RectBivariateSpline

        for i in range(r.shape[0]):  # a silent corner: filled from its neighbours along v_B (never played)
            ok = ~np.isnan(r[i])
            if not ok.all():
                r[i] = np.interp(vbs, vbs[ok], r[i][ok]) if ok.any() else np.nanmean(r)
        spline = RectBivariateSpline(logb, vbs, r, kx=3, ky=3)
        self.g_logb = np.linspace(logb[0], logb[-1], DENSE[0])
        self.g_vb = np.linspace(vbs[0], vbs[-1], DENSE[1])
        self.g_ratio = spline(self.g_logb, self.g_vb)

    def grid_ratio(self, beta: float, vb: float) -> float:
        """The sounding ratio at a bow off the velocity table: the grid's spline, bilinear in its dense table."""
        gb, gv = self.g_logb, self.g_vb
        x = min(max((math.log(beta) - gb[0]) / (gb[1] - gb[0]), 0.0), len(gb) - 1.0)
        y = min(max((vb - gv[0]) / (gv[1] - gv[0]), 0.0), len(gv) - 1.0)
        i, j = min(int(x), len(gb) - 2), min(int(y), len(gv) - 2)
        fx, fy = x - i, y - j
        r = self.g_ratio
        return float((1 - fx) * ((1 - fy) * r[i, j] + fy * r[i, j + 1]) + fx * ((1 - fy) * r[i + 1, j]
                                                                                 + fy * r[i + 1, j + 1]))

    @staticmethod
    def default_model(models, a: float):
        """The validated model that covers the most velocities at neutral controllers, so that one model plays the
        keyboard; the other velocities play the FDM. Ties: the larger box of bows (a note whose CC2 / CC11 moved its
        bow stays on the operator: `velocity-soft` covers velocities 1-109 as `soft-range` does, but not v_B below
        0.155), then the lowest validation NMSE."""
        best, score = None, (-1, 0.0, 0.0)
        betas = np.array([M.bow_beta(v) for v in range(1, 128)])
        vbs = np.array([M.bow_vb(v) for v in range(1, 128)])
        for m in models:
            if m.failure is not None or not math.isclose(m.domain.a, a, rel_tol=1e-9):
                continue
            # a stick-slip bow plays no note live (Stream._plays): it would hand its velocity to the FDM
            soft = np.array([not needs_whole_windows(m.domain, b) for b in betas])
            n = int(np.sum(m.domain.box_contains(betas, vbs) & soft))
            s = (n, m.domain.bow_extent, -float((m.meta.validation or {}).get("nmse", math.inf)))
            if n and s > score:
                best, score = m, s
        if best is None:
            raise DomainError("no validated operator model plays any MIDI velocity; play with --method fdm or train "
                              "one (bowsynth train --f0 100 --fb 6.283:282.7 --vb 0:0.3)")
        return best
