"""Screenshots of the two listening-report pages for the README (docs/report-compare.png, docs/report-models.png).

    python benchmarks/report_screenshots.py [--out docs] [--keep DIR]

Renders the README's crescendo through the shipped range model, writes `compare --report` and `models --report`
(the default 3 x 3 grid: about half a minute), and photographs them in headless Debian chromium (playwright, no
browser download; `make setup` installs both). The models picture shows the summary and the range model's section:
the point models' sections are hidden for the picture only, to keep it readable."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--no-first-run"]


def bowsynth(*args, cwd) -> None:
    print("$ bowsynth " + " ".join(map(str, args)), flush=True)
    subprocess.run([sys.executable, "-m", "bowsynth", *map(str, args)], cwd=cwd, check=True)


def shoot(page: Path, png: Path, hide: str | None = None) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", args=FLAGS, headless=True)
        ctx = b.new_context(viewport={"width": 1280, "height": 900})
        ctx.route("**/*", lambda r: r.continue_() if r.request.url.startswith(("file:", "data:")) else r.abort())
        pg = ctx.new_page()
        pg.goto(page.resolve().as_uri(), wait_until="load")
        pg.wait_for_function("Array.from(document.querySelectorAll('audio')).every(a => a.readyState >= 1)")
        if hide:
            pg.evaluate(f"document.querySelectorAll({hide!r}).forEach(e => e.style.display = 'none')")
        pg.screenshot(path=str(png), full_page=True)
        b.close()
    print(f"wrote {png}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs")
    ap.add_argument("--keep", type=Path, help="Keep the pages and the render in this directory.")
    a = ap.parse_args()
    work = a.keep or Path(tempfile.mkdtemp(prefix="bowsynth-report-"))
    work.mkdir(parents=True, exist_ok=True)
    bowsynth("render", "--fb", "50@0,200@2", "--vb", "0.15", "-d", "2", "cresc.wav", "--force", cwd=work)
    bowsynth("compare", "cresc.wav", "--report", "compare.html", "--force", cwd=work)
    bowsynth("models", "--report", "models.html", "--force", cwd=work)
    shoot(work / "compare.html", a.out / "report-compare.png")
    shoot(work / "models.html", a.out / "report-models.png",
          hide="section[id^='model-paper'], section[id^='model-scratch']")


if __name__ == "__main__":
    main()
