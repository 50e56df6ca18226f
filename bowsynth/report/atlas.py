"""The tiling of the bow plane: each model's box of F_B / w and v_B drawn over the playing space (`models --map`)."""

from __future__ import annotations

import math
from pathlib import Path

SPACE = ((0.005, 2.1), (0.0, 0.3))  # the playing space's F_B / w (log axis) and v_B, with a margin


def draw_atlas(models, path: Path) -> Path:
    """Draw every model's box (range models as rectangles, point models as dots; failed ones hatched) to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    from .. import physics
    from ..io.outfile import atomic_write

    fig, ax = plt.subplots(figsize=(10, 6.5), dpi=110)
    colours = {1.0: "#1f77b4", 0.5: "#2ca02c", 0.25: "#d62728"}
    for m in sorted(models, key=lambda m: -(m.domain.bow_extent if m.domain.is_range else 0.0)):
        d = m.domain
        share = round(d.window / (2 * math.pi), 2)
        c = colours.get(share, "#7f7f7f")
        if not d.is_range:
            ax.plot([d.beta], [d.vb], "o", color=c, ms=6, mec="k")
            ax.annotate(m.path.stem if m.path else m.meta.name, (d.beta, d.vb), fontsize=6, xytext=(4, 4),
                        textcoords="offset points")
            continue
        b0, b1, v0, v1 = d.box
        failed = m.failure is not None
        ax.add_patch(Rectangle((max(b0, SPACE[0][0]), v0), b1 - max(b0, SPACE[0][0]), v1 - v0, fill=not failed,
                               alpha=0.12 if not failed else 0.9, facecolor=c, edgecolor="#b00" if failed else c,
                               hatch="///" if failed else None, lw=0.8))
        if (math.log(b1 / max(b0, SPACE[0][0])) * (v1 - v0)) > 0.02 and not failed:
            ax.text(math.sqrt(max(b0, SPACE[0][0]) * b1), v0 + 0.5 * (v1 - v0), m.path.stem if m.path else m.meta.name,
                    fontsize=6, ha="center", va="center", color="k")
    ax.axhline(physics.vb_stop(100.0), color="k", lw=0.6, ls="--")
    ax.text(SPACE[0][0] * 1.1, physics.vb_stop(100.0) + 0.002, "vb_stop (a = 100): below it the bow damps the mass",
            fontsize=7)
    ax.set_xscale("log")
    ax.set_xlim(*SPACE[0])
    ax.set_ylim(*SPACE[1])
    ax.set_xlabel("F_B / w (bow force over angular frequency)")
    ax.set_ylabel("v_B (m/s)")
    ax.set_title(f"{len(models)} operator models: blue full-period windows, green half, red quarter (stick-slip); "
                 "hatched: failed validation", fontsize=9)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)
    return path
