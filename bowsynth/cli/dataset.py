"""`bowsynth dataset`: a labelled corpus of notes and gestures drawn from a spec, on Ray or in this process."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .app import app, err, out


@app.command()
def dataset(
    spec: Path = typer.Argument(..., help="The corpus's spec (TOML: count, seed, duration, sample_rate, f0, beta, vb, gestures; docs/cluster.md)."),
    out_dir: Path = typer.Option(..., "--out", "-o", help="The corpus's directory (created; a rerun finishes what is missing)."),
    workers: int = typer.Option(1, "--workers", "-j", min=1, max=1024, help="Ray workers on this machine (1: this process)."),
    address: Optional[str] = typer.Option(None, "--address", help="A Ray cluster's address (host:port; default RAY_ADDRESS): its workers render."),
    with_reference: bool = typer.Option(False, "--with-reference", help="Also the x100 FDM of every note (reference/), for supervised work."),
):
    """Render a labelled corpus of notes and gestures (audio files and metadata.jsonl, the layout Hugging Face
    datasets loads as an audiofolder)."""
    import math

    from ..corpus.build import build
    from ..corpus.spec import read_spec

    s = read_spec(spec)
    with err.status("dataset: drawing the notes") as status:
        def progress(done, total, eta):
            left = "" if not math.isfinite(eta) else f", about {eta:.0f} s left"
            status.update(f"dataset: {done}/{total} notes{left}")
        b = build(s, out_dir, workers=workers, address=address, reference=with_reference, progress=progress)
    if b.note:
        err.print(f"note: {b.note}", soft_wrap=True)
    out.print(f"{out_dir}: {b.kept + b.written} of {b.total} notes ({b.written} rendered now, {b.kept} already there) "
              f"in {b.seconds:.1f} s; load it with datasets.load_dataset(\"audiofolder\", data_dir=\"{out_dir}\")",
              soft_wrap=True)
    if b.interrupted:
        err.print("interrupted: the notes written so far are whole and listed; run the same command again to finish")
        return 130
