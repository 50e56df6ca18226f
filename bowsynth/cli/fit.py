"""`bowsynth fit`: the bow and f0 that make the operator sound like a recording, written as a score."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .app import app, err, out


@app.command()
def fit(
    target: Path = typer.Argument(..., help="A mono recording of a held note of this instrument (any rate, any gain)."),
    out_path: Path = typer.Option(Path("fitted.toml"), "--out", "-o", help="The score to write (TOML, what `bowsynth score` plays)."),
    curves: bool = typer.Option(False, "--curves", help="Also fit the bow as curves (breakpoints every 0.1 s) from the held fit: for a gesture (a crescendo, a bow-speed change)."),
    starts: int = typer.Option(3, "--starts", min=1, max=8, help="The best coarse bows that are refined (zoom and gradient descent)."),
    report: Optional[Path] = typer.Option(None, "--report", help="Also write an HTML page: the target and the fit to listen to, their harmonics, the bow plane as the search saw it, the curves."),
    force: bool = typer.Option(False, "--force", help="Write the fit even where it is not a match; replace a read-only --out."),
):
    """Find the held bow (F_B / w, v_B) and f0 that make the operator sound like TARGET: a coarse search, then
    gradient descent through the operator. Says how well the sound determines each part of the bow."""
    import time

    from .. import api
    from ..fit import held
    from ..fit.target import FitMiss, read_target
    from ..fit.write import determined, write_score
    from ..io.outfile import check_not_input, check_output_path

    t0 = time.monotonic()
    check_not_input(out_path, [target], "--out")
    check_output_path(out_path, force=force)
    if report is not None:
        check_not_input(report, [target, out_path], "--report")
        check_output_path(report, force=force)
    t = read_target(target)  # a bad file is refused before torch is imported
    with err.status("fitting: coarse search") as status:
        def progress(stage, done, total):
            status.update(f"fitting: {stage} {done + 1}/{total}" if total > 1 else f"fitting: {stage}")
        got = api.fit(target, starts=starts, progress=progress, curves=curves)
    f, c = got if curves else (got, None)
    b, ch = f.best, f.checked
    loss = b.loss if c is None else min(b.loss, c.loss)  # a gesture is matched by its curves
    match = loss <= held.MISS_LOSS
    if not match and not force:
        raise FitMiss(f"the nearest note of this instrument is {loss:.3g} away (loss; a note of it is within "
                      f"{held.MISS_LOSS:g}): {target} is not a match; nothing written (--force writes it)")
    write_score(f, out_path, target.name, t.seconds, force=True, curves=c)
    if report is not None:
        from ..report.fit_page import fit_page
        from ..report.html import write_page

        write_page(report, fit_page(t, f, api.render, c), force=force)
    out.print(f"wrote {out_path}: f0 {b.f0:.6g} Hz, F_B {f.fb:.6g} (F_B / w {b.beta:.5g}), v_B {b.vb:.5g}"
              f"{'' if match else ' (not a match: written by --force)'}", soft_wrap=True)
    out.print(f"how well the sound determines it: F_B / w {determined(f, 'beta')}, v_B {determined(f, 'vb')}",
              soft_wrap=True)
    for other in f.alike:
        out.print(f"sounds alike: F_B / w {other.beta:.4g}, v_B {other.vb:.4g}", soft_wrap=True)
    out.print(f"the fitted note against the target: harmonics {ch['harmonics_db']:.2f} dB (median), pitch "
              f"{ch['pitch_cents']:+.2f} cents, onset {ch['onset_ms']:+.1f} ms; {f.evaluations} notes played, "
              f"the whole command {time.monotonic() - t0:.1f} s", soft_wrap=True)
    if c is not None:
        ident = c.identifiable()
        cc = c.checked
        out.print(f"curves: {len(c.times)} breakpoints, f0 {c.f0:.6g} Hz; the sound determines F_B / w at "
                  f"{int(ident[:, 0].sum())} and v_B at {int(ident[:, 1].sum())} of them; per 100 ms frame against "
                  f"the target: harmonics {cc['harmonics_db']:.2f} dB (median), pitch {cc['pitch_cents']:.2f} cents"
                  f"{'; the curves reach the edge of the one model the fit rolls' if c.at_edge else ''}",
                  soft_wrap=True)
    if f.interrupted or (c is not None and c.interrupted):
        err.print("interrupted: the best fit so far was written")
        return 130
