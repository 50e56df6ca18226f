"""The error map (`analysis.error_map`) as a reader sees it: Markdown tables, one grid per pitch, and a picture of the
harmonic and pitch errors over (F_B / w, v_B)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..analysis.error_map import summary
from ..io.text import num

# What a cell shows where the operator has no number: the truth is silent, or no model plays the bow
SILENT_MARK, UNPLAYED_MARK = "·", "✗"


def _cell_text(c: dict) -> str:
    if c["status"] == "silent":
        return SILENT_MARK if c.get("op_silent", True) else f"{SILENT_MARK} (op sounds)"
    if c["status"] == "not played":
        return UNPLAYED_MARK
    op = c["op"]
    return f"{num(op['harm_db_median'], '.2f')} dB, {num(abs(op['cents']), '.2f')} c"


def _pair(v) -> str:
    return f"{num(v[0], '.3g')} / {num(v[1], '.3g')}"


def table(res: dict) -> str:
    """The summary over all pitches, then each pitch's grid: rows v_B (fastest bow on top), columns F_B / w; a
    played cell gives the operator's median harmonic error (dB) and |pitch error| (cents), SILENT_MARK where the
    truth is silent, UNPLAYED_MARK where no model plays the bow. The models that played are listed under each grid."""
    s = summary(res)
    lines = [f"Cells where the truth sounds: {s['sounding']}; played by the operator: {s['played']}; silent: "
             f"{s['silent']} (the operator sounds in {s['silent_op_sounds']} of them). {res['seconds']:g} s notes from "
             f"rest against a x100 FDM, the operator in {res.get('windows', 'free')} windows; medians / worsts over "
             "the played cells:", "",
             "| engine | harmonics (dB) | pitch (cents) | onset (ms) | NMSE(p) |", "|---|---|---|---|---|"]
    for who, name in (("op", "operator"), ("fdm", "audio-rate FDM (same cells)")):
        w = s[who]
        lines.append(f"| {name} | {_pair(w['harm_db'])} | {_pair(w['cents'])} | {_pair(w['onset_err_ms'])} "
                     f"| {_pair(w['nmse'])} |")
    for f0 in res["f0"]:
        cells = cells_of(res, f0)
        lines += ["", f"f0 {f0:g} Hz (rows v_B, columns F_B / w):", "",
                  "| v_B \\ F_B / w | " + " | ".join(f"{b:.3g}" for b in res["beta"]) + " |",
                  "|---" * (len(res["beta"]) + 1) + "|"]
        for vb in reversed(res["vb"]):
            lines.append(f"| {vb:.3g} | " + " | ".join(_cell_text(cells[(b, vb)]) for b in res["beta"]) + " |")
        names = sorted({c.get("model_name") for c in cells.values() if c["status"] == "played"} - {None})
        lines += ["", "played by: " + (", ".join(names) if names else "no model")]
    return "\n".join(lines)


def cells_of(res: dict, f0: float) -> dict:
    """The cells at one pitch by (F_B / w, v_B)."""
    return {(c["beta"], c["vb"]): c for c in res["cells"] if c["f0"] == f0}


def _grid_values(res: dict, f0: float, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(values, status) arrays (v_B rows x F_B / w columns): the operator's |key| where played, NaN elsewhere;
    status 0 played, 1 silent, 2 not played."""
    cells = cells_of(res, f0)
    val = np.full((len(res["vb"]), len(res["beta"])), np.nan)
    status = np.zeros_like(val, dtype=int)
    for i, vb in enumerate(res["vb"]):
        for j, b in enumerate(res["beta"]):
            c = cells[(b, vb)]
            if c["status"] == "played":
                val[i, j] = abs(c["op"][key])
            else:
                status[i, j] = 1 if c["status"] == "silent" else 2
    return val, status


def _edges(x: list[float], log: bool) -> np.ndarray:
    """Cell edges around centres x (geometric midpoints on a log axis)."""
    x = np.asarray(x, float)
    if len(x) == 1:
        return np.array([x[0] / 1.5, x[0] * 1.5]) if log else np.array([x[0] - 0.02, x[0] + 0.02])
    t = np.log(x) if log else x
    mid = (t[1:] + t[:-1]) / 2
    e = np.concatenate([[2 * t[0] - mid[0]], mid, [2 * t[-1] - mid[-1]]])
    return np.exp(e) if log else e


def plot(res: dict, path) -> None:
    """One row per pitch: the operator's median harmonic error (dB) and |pitch error| (cents) over (F_B / w, v_B), on
    log colour scales; grey hatched where no model plays, white where the truth is silent."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from ..io.outfile import atomic_write

    f0s = res["f0"]
    fig, axes = plt.subplots(len(f0s), 2, figsize=(12, 4.2 * len(f0s)), squeeze=False)
    be, ve = _edges(res["beta"], True), _edges(res["vb"], False)
    for row, f0 in zip(axes, f0s):
        for ax, (key, label, lo, hi) in zip(row, (("harm_db_median", "harmonics: median error (dB)", 0.01, 30.0),
                                                  ("cents", "pitch: |error| (cents)", 0.01, 100.0))):
            val, status = _grid_values(res, f0, key)
            shown = np.clip(val, lo, hi)
            m = ax.pcolormesh(be, ve, np.ma.masked_invalid(shown), norm=LogNorm(lo, hi), cmap="viridis")
            unplayed = np.ma.masked_where(status != 2, np.ones_like(val))
            ax.pcolormesh(be, ve, unplayed, cmap="Greys", vmin=0, vmax=2.5)
            for i, vb in enumerate(res["vb"]):
                for j, b in enumerate(res["beta"]):
                    if status[i, j] == 0 and math.isfinite(val[i, j]):
                        ax.text(b, vb, f"{val[i, j]:.2g}", ha="center", va="center", fontsize=6,
                                color="w" if val[i, j] < math.sqrt(lo * hi) else "k")
                    elif status[i, j] == 1:
                        sounds = cells_of(res, f0)[(b, vb)].get("op_silent") is False
                        ax.text(b, vb, "op\nsounds" if sounds else "silent", ha="center", va="center", fontsize=5.5,
                                color="tab:red" if sounds else "0.5")
                    else:
                        ax.text(b, vb, UNPLAYED_MARK, ha="center", va="center", fontsize=7, color="0.3")
            ax.set_xscale("log")
            ax.set_xlabel("F_B / w")
            ax.set_ylabel("v_B (m/s)")
            ax.set_title(f"f0 {f0:g} Hz, {label}", fontsize=9)
            fig.colorbar(m, ax=ax, shrink=0.85)
    fig.suptitle(f"operator against a x100 FDM, {res['seconds']:g} s notes from rest (grey {UNPLAYED_MARK}: no model "
                 "plays; silent: the truth is; op sounds: the operator is not)",
                 fontsize=10)
    fig.tight_layout()
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)
