"""`bowsynth bench`: speed and accuracy of the shipped models against the FDM, as tables, plots and JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import app, out


@app.command()
def bench(
    what: str = typer.Argument("all", help="What to benchmark: fdm, equal (the operator against the FDM at equal accuracy, 100/440/880 Hz), or all (FDM and operators, speed against error)."),
    quick: bool = typer.Option(False, "--quick", help="A small, fast run."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON instead of Markdown."),
    out_prefix: Optional[Path] = typer.Option(None, "--out", help="Also write PREFIX.md, PREFIX.json and PREFIX.png."),
    anchors: Optional[Path] = typer.Option(None, "--anchors", help="Directory of the paper's rollouts (.npz) to "
                                                                   "score too (default: shared/anchors, ../shared/anchors or tests/data under the current directory, the first present)."),
    force: bool = typer.Option(False, "--force", help="Replace read-only --out files."),
):
    """Benchmark speed against error: FDM at several rates and each operator, against a high-rate FDM."""
    import json

    from ..analysis.bench import bench_fdm
    from ..report import bench_report as B

    if what not in ("fdm", "equal", "all"):
        raise UsageError(f"bench target must be fdm, equal or all, got {what!r}")
    if out_prefix is not None:
        from ..io.outfile import check_output_path

        for ext in (".md", ".json", ".png"):
            check_output_path(out_prefix.with_suffix(ext), force=force)
    if what == "fdm":
        rows = bench_fdm(quick=quick)
        out.print(json.dumps(rows, indent=2) if json_out else B.fdm_table(rows), soft_wrap=True)
        return
    if what == "equal":
        res = B.run_equal(quick=quick, out_prefix=out_prefix)
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
