"""The error over the playing space: a grid of bows, F_B / w by v_B, at one pitch or several, each note
rendered from rest by the operator the renderer picks (no --model) and by the audio-rate FDM, both against a x100 FDM
at the same f0 and bow. Per cell: who plays (a model, or why none), and what a listener hears (harmonic dB, pitch
cents, onset ms: `metrics.listener_errors`), NMSE beside them.

A cell is one of
- "played": the operator rendered the note; its errors are in the cell,
- "not played": no validated model covers the bow, or the rollout left its trained states (the reason is kept),
- "silent": the truth does not sound (the bow damps the mass below v_B = 1 / sqrt(2a), a note too slow to speak
  within the render); the operator is checked for silence there too ("op_silent").
"""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np

from ..engines import render
from ..engines.fdm import TRUTH_OVERSAMPLE
from ..errors import BowsynthError
from ..music.engine_tuning import check_windows, sounding_for
from ..scene import Scene
from ..metrics import listener_errors, nmse, note_sounds

BETA_RANGE = (0.02, 2.0)  # F_B / w across the playing space (0 is a lifted bow: silence, nothing to map)
VB_RANGE = (0.0, 0.28)  # v_B from a stopped bow to the fastest the playing space holds


def grid(n_beta: int, n_vb: int, beta_range=BETA_RANGE, vb_range=VB_RANGE) -> tuple[list[float], list[float]]:
    """The cells' bows: F_B / w log-spaced (a factor 100 across the space), v_B evenly spaced, ends included."""
    if n_beta < 1 or n_vb < 1:
        raise ValueError(f"the grid needs at least 1 x 1 cells, got {n_beta} x {n_vb}")
    lo, hi = beta_range
    betas = [lo] if n_beta == 1 else list(np.geomspace(lo, hi, n_beta))
    vbs = [vb_range[0]] if n_vb == 1 else list(np.linspace(*vb_range, n_vb))
    return [float(b) for b in betas], [float(v) for v in vbs]


def map_cell(f0: float, beta: float, vb: float, seconds: float = 2.0, model=None, windows: str | None = None) -> dict:
    """One cell: the truth (x100 FDM), the audio-rate FDM and the operator (`model`, or the renderer's pick; its
    windows as `api.render`'s, None its default) at (f0, F_B / w, v_B)."""
    sc = Scene(f0=f0, fb=beta * 2.0 * math.pi * f0, vb=vb, duration=seconds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = render(sc, engine="fdm", oversample=TRUTH_OVERSAMPLE)
        fdm = render(sc, engine="fdm")
    cell = {"f0": f0, "beta": beta, "vb": vb}
    sounds = note_sounds(truth.p)
    if sounds:
        cell["fdm"] = {**listener_errors(fdm.p, truth.p, sc.sample_rate), "nmse": nmse(fdm.p, truth.p)}
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            op = render(sc, engine="operator", model=model, sounding=sounding_for(sc, windows, model))
    except BowsynthError as e:
        cell.update(status="not played", why=str(e).splitlines()[0].split(";")[0][:200])
        return cell
    cell["op_seconds"] = time.perf_counter() - t0
    cell["model"] = op.info.model_id
    cell["model_name"] = Path(op.info.model_path).stem if op.info.model_path else op.info.model_id
    if not sounds:
        cell.update(status="silent", op_silent=not note_sounds(op.p))
        return cell
    cell.update(status="played", op={**listener_errors(op.p, truth.p, sc.sample_rate), "nmse": nmse(op.p, truth.p)})
    return cell


def _cell(args: tuple) -> dict:
    """A task: one cell (map_cell's arguments as a tuple, so that a pool can ship it)."""
    return map_cell(*args)


def error_map(f0s=(110.0, 440.0), n_beta: int = 10, n_vb: int = 8, seconds: float = 2.0, model=None,
              progress=None, windows: str | None = None, workers: int = 1, address: str | None = None) -> dict:
    """Every cell of the grid at every pitch in f0s (see map_cell; windows None: a render's default). progress(done,
    total), if given, after each. workers / address: the cells as independent tasks (`io.cluster.Pool`: Ray, or
    processes here); the cells come back in the grid's order whatever order they finish in. A model given as an
    object goes to the tasks as its file."""
    from ..io.cluster import Pool

    windows = check_windows(windows)
    betas, vbs = grid(n_beta, n_vb)
    if model is not None and not isinstance(model, (str, Path)) and not (workers == 1 and address is None):
        model = str(model.path)
    todo = [(float(f0), beta, vb, seconds, model, windows) for f0 in f0s for vb in vbs for beta in betas]
    cells: list = [None] * len(todo)
    t0 = time.perf_counter()
    done = 0
    with Pool(workers, address) as pool:
        for i, cell in pool.map(_cell, todo):
            cells[i] = cell
            done += 1
            if progress:
                progress(done, len(todo))
    return {"f0": [float(f) for f in f0s], "beta": betas, "vb": vbs, "seconds": seconds, "windows": windows,
            "cells": cells, "wall_s": time.perf_counter() - t0}


def summary(res: dict) -> dict:
    """Over the cells where the truth sounds: how many the operator plays, and the medians and worsts of its
    harmonic error (each cell's median over harmonics), |cents| and onset error, with the audio-rate FDM's beside."""
    sounding = [c for c in res["cells"] if c.get("status") != "silent" and "fdm" in c]
    played = [c for c in sounding if c["status"] == "played"]

    def stats(rows, key, f=abs):
        v = np.array([f(r[key]) for r in rows], float)
        v = v[np.isfinite(v)]
        return (float(np.median(v)), float(np.max(v))) if len(v) else (math.nan, math.nan)

    out = {"sounding": len(sounding), "played": len(played),
           "silent": sum(c.get("status") == "silent" for c in res["cells"]),
           "silent_op_sounds": sum(c.get("status") == "silent" and not c.get("op_silent", True)
                                   for c in res["cells"])}
    for who, rows in (("op", [c["op"] for c in played]), ("fdm", [c["fdm"] for c in played])):
        out[who] = {"harm_db": stats(rows, "harm_db_median"), "cents": stats(rows, "cents"),
                    "onset_err_ms": stats(rows, "onset_err_ms"), "nmse": stats(rows, "nmse")}
    return out
