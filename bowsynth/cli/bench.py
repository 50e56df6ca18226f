"""`bowsynth bench`: speed and accuracy of the shipped models against the FDM, as tables, plots and JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import app, out


@app.command()
def bench(
    what: str = typer.Argument("all", help="What to benchmark: fdm, equal (the operator against the FDM at equal accuracy, 100/440/880 Hz), map (the operator's listener errors over the playing space, F_B / w x v_B), or all (FDM and operators, speed against error)."),
    quick: bool = typer.Option(False, "--quick", help="A small, fast run."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON instead of Markdown."),
    out_prefix: Optional[Path] = typer.Option(None, "--out", help="Also write PREFIX.md, PREFIX.json and PREFIX.png."),
    anchors: Optional[Path] = typer.Option(None, "--anchors", help="Directory of the paper's rollouts (.npz) to "
                                                                   "score too (default: shared/anchors, ../shared/anchors or tests/data under the current directory, the first present)."),
    force: bool = typer.Option(False, "--force", help="Replace read-only --out files."),
    f0: str = typer.Option("110,440", "--f0", help="map: the pitches (Hz), comma-separated."),
    grid: str = typer.Option("10x8", "--grid", help="map: cells, F_B / w x v_B (F_B / w 0.02-2 log-spaced, v_B 0-0.28)."),
    seconds: float = typer.Option(2.0, "--seconds", help="map: each note's length from rest (s); errors over its second half."),
    model: Optional[str] = typer.Option(None, "--model", help="map: this model (a path, or a name in ./models or the shipped ones) plays every cell it covers, instead of the renderer's pick: a candidate before it ships; equal: these models (comma-separated) instead of the shipped ones."),
    windows: Optional[str] = typer.Option(None, "--windows",
                                          help="map and equal: the operator's windows, as render's (free, locked, "
                                               "physics or auto); default auto, what a render plays (free: the "
                                               "trained windows)."),
    workers: int = typer.Option(1, "--workers", "-j", min=1, max=1024, help="map and equal: the cells (a model each) as tasks on Ray workers of this machine (1: one after another here)."),
    address: Optional[str] = typer.Option(None, "--address", help="map and equal: a Ray cluster's address (default RAY_ADDRESS)."),
):
    """Benchmark speed against error: FDM at several rates and each operator, against a high-rate FDM."""
    import json

    from ..analysis.bench import bench_fdm
    from ..report import bench_report as B

    if what not in ("fdm", "equal", "map", "all"):
        raise UsageError(f"bench target must be fdm, equal, map or all, got {what!r}")
    from ..music.engine_tuning import check_windows

    windows = check_windows(windows)  # None: render's default, so that the numbers are what a render plays
    if what == "map":
        map_args = _map_args(f0, grid, seconds)
        if model is not None:
            from ..engines.operator.choose import as_model

            model = as_model(model)  # read once (a bad file is one line here, not one per cell)
    if out_prefix is not None:
        from ..io.outfile import check_output_path

        for ext in (".md", ".json", ".png"):
            check_output_path(out_prefix.with_suffix(ext), force=force)
    if what == "fdm":
        rows = bench_fdm(quick=quick)
        out.print(json.dumps(rows, indent=2) if json_out else B.fdm_table(rows), soft_wrap=True)
        return
    if what == "map":
        _bench_map(map_args, out_prefix, json_out, force, model, windows, workers, address)
        return
    if what == "equal":
        models = [m.strip() for m in model.split(",") if m.strip()] if model else None
        if models:
            from ..engines.operator.choose import as_model

            for m in models:
                as_model(m)  # read here: a bad name or file is one line before any task starts
        res = B.run_equal(quick=quick, out_prefix=out_prefix, windows=windows, models=models, workers=workers,
                          address=address)
        md, js = B.equal_table(res), json.dumps(B.to_json(res), indent=2)
        _write(out_prefix, md, js, force)
        out.print(js if json_out else md, soft_wrap=True)
        return
    if anchors is not None and not anchors.is_dir():
        raise UsageError(f"--anchors {anchors} is not a directory")
    res = B.run_all(quick=quick, out_prefix=out_prefix, anchor_dir=anchors or B.default_anchors())
    md, js = B.to_markdown(res), json.dumps(B.to_json(res), indent=2)
    _write(out_prefix, md, js, force)
    out.print(js if json_out else md, soft_wrap=True)


def _write(out_prefix: Optional[Path], md: str, js: str, force: bool) -> None:
    if out_prefix is not None:
        from ..io.outfile import atomic_write

        atomic_write(out_prefix.with_suffix(".md"), lambda t: Path(t).write_text(md + "\n"), force=force)
        atomic_write(out_prefix.with_suffix(".json"), lambda t: Path(t).write_text(js + "\n"), force=force)


def _map_args(f0: str, grid: str, seconds: float) -> tuple:
    """(pitches, n_beta, n_vb, seconds) from the map's flags, or a UsageError naming the flag."""
    import math

    try:
        f0s = tuple(float(v) for v in f0.split(","))
    except ValueError:
        raise UsageError(f"--f0 must be pitches in Hz, comma-separated (110,440), got {f0!r}") from None
    if not all(math.isfinite(v) and 20.0 <= v <= 4000.0 for v in f0s):
        raise UsageError(f"--f0 pitches must be within 20-4000 Hz, got {f0!r}")
    try:
        nb, nv = (int(v) for v in grid.lower().split("x"))
    except ValueError:
        raise UsageError(f"--grid must be CELLSxCELLS (10x8), got {grid!r}") from None
    if not (1 <= nb <= 40 and 1 <= nv <= 40):
        raise UsageError(f"--grid must be 1x1 to 40x40 cells, got {grid!r}")
    if not (math.isfinite(seconds) and 0.2 <= seconds <= 10.0):
        raise UsageError(f"--seconds must be 0.2-10 s for a map, got {seconds!r}")
    return f0s, nb, nv, seconds


def _bench_map(args: tuple, out_prefix: Optional[Path], json_out: bool, force: bool, model, windows: str,
               workers: int = 1, address: Optional[str] = None) -> None:
    import json

    from ..analysis.error_map import error_map
    from ..report import error_map as R
    from ..io.text import jsonable
    from .app import err

    f0s, nb, nv, seconds = args

    def progress(done: int, total: int) -> None:  # a line at each tenth: a map takes minutes
        if done == total or done % max(1, total // 10) == 0:
            err.print(f"bench map: {done}/{total} cells")

    res = error_map(f0s, nb, nv, seconds, model=model, progress=progress, windows=windows, workers=workers,
                    address=address)
    md, js = R.table(res), json.dumps(jsonable(res), indent=2)
    _write(out_prefix, md, js, force)
    if out_prefix is not None:
        R.plot(res, out_prefix.with_suffix(".png"))
    out.print(js if json_out else md, soft_wrap=True)
