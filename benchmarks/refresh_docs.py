"""Rewrite the docs' generated tables: each block between `<!-- generated: COMMAND -->` and `<!-- end generated -->`
becomes COMMAND and what it prints now (run by the shell from the checkout's top, one block after another).

    .venv/bin/python benchmarks/refresh_docs.py [docs/BENCHMARKS.md ...] [--only TEXT] [--list]

`make bench-docs` runs it over every page of docs/ (BENCHMARKS.md about 15 minutes on this 2-core machine, fit.md's
fits about 25 more). --only: the blocks whose
command contains TEXT; --list: print the commands and stop. A command that fails leaves its block as it was, says so,
and the run ends with exit 1. Each block ends with a line naming the machine and its load when the command started,
since the numbers' times depend on them. What each command printed on stderr (a benchmark's rows bow by bow) is kept
in build/bench-docs/, a file a block.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT / "build" / "bench-docs"
BLOCK = re.compile(r"(<!-- generated: (?P<cmd>[^\n]+?) -->\n)(?P<body>.*?)(<!-- end generated -->)", re.DOTALL)


def blocks(text: str) -> list[re.Match]:
    """The generated blocks of a document, in order."""
    return list(BLOCK.finditer(text))


def machine() -> str:
    """This machine in a few words: its CPU, its cores, its load now."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f} at the start"


def refresh(path: Path, only: str | None = None, run=None, logs: Path | None = LOGS) -> list[str]:
    """Rewrite the blocks of one document whose command contains `only` (all where None); returns the commands that
    failed. `run(cmd) -> (exit code, stdout, stderr)`, the shell by default; each command's stderr kept in `logs`."""
    def shell(cmd):
        p = subprocess.run(cmd, shell=True, cwd=ROOT, capture_output=True, text=True)
        return p.returncode, p.stdout, p.stderr

    run = run or shell
    text = path.read_text()
    failed = []
    out, at = [], 0
    for m in blocks(text):
        out.append(text[at:m.start("body")])
        body = m.group("body")
        cmd = m.group("cmd")
        if only is None or only in cmd:
            where = machine()
            print(f"{path.name}: {cmd}", file=sys.stderr, flush=True)
            code, stdout, stderr = run(cmd)
            if logs is not None:
                logs.mkdir(parents=True, exist_ok=True)
                (logs / (re.sub(r"[^A-Za-z0-9]+", "-", cmd.split("benchmarks/")[-1]).strip("-")[:120] + ".log")) \
                    .write_text(stderr)
            if code == 0 and stdout.strip():
                body = f"    {cmd}\n\n{stdout.strip()}\n\n(measured on {where})\n"
            else:
                failed.append(cmd)
                tail = (stderr.strip().splitlines() or ["no output"])[-1]
                print(f"{path.name}: failed ({code}): {cmd}: {tail}", file=sys.stderr)
        out.append(body)
        at = m.end("body")
    out.append(text[at:])
    new = "".join(out)
    if new != text:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(new)
        tmp.replace(path)
    return failed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("docs", nargs="*", type=Path, default=sorted((ROOT / "docs").glob("*.md")))
    ap.add_argument("--only", default=None)
    ap.add_argument("--list", action="store_true")
    a = ap.parse_args(argv)
    failed = []
    for doc in a.docs:
        if a.list:
            for m in blocks(doc.read_text()):
                print(f"{doc}: {m.group('cmd')}")
            continue
        failed += refresh(doc, a.only)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
