"""The docs' generated tables: benchmarks/refresh_docs.py rewrites each block with its command's output, and every
block in the docs names a benchmark that runs."""

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import refresh_docs  # noqa: E402

DOC = """# Numbers

Prose before, that names the markers inline: the tables between `<!-- generated: COMMAND -->` and
`<!-- end generated -->` are written by COMMAND.

<!-- generated: echo one -->
| old | table |
<!-- end generated -->

Prose between, kept as written.

<!-- generated: false -->
| a table a failed command leaves |
<!-- end generated -->

<!-- generated: echo two -->
stale
<!-- end generated -->
Prose after.
"""


def fake_run(cmd):
    return (0, f"| {cmd.split()[-1]} |\n", "") if cmd.startswith("echo") else (1, "", "it broke\n")


def test_a_refresh_rewrites_each_block_with_its_command_and_output_and_leaves_the_rest(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text(DOC)
    failed = refresh_docs.refresh(doc, run=fake_run, logs=tmp_path / "logs")
    text = doc.read_text()
    assert failed == ["false"]
    assert (tmp_path / "logs" / "false.log").read_text() == "it broke\n"  # what each command said on stderr
    assert "    echo one\n\n| one |\n\n(measured on " in text and "    echo two\n\n| two |" in text
    assert "| old | table |" not in text and "stale" not in text
    assert "| a table a failed command leaves |" in text  # kept as it was
    for kept in ("# Numbers\n\nProse before, that names the markers inline", "Prose between, kept as written.", "Prose after.\n"):
        assert kept in text
    assert len(refresh_docs.blocks(text)) == 3
    again = text
    refresh_docs.refresh(doc, only="two", run=fake_run, logs=None)  # only the blocks whose command holds "two"
    assert doc.read_text().split("echo two")[0] == again.split("echo two")[0]


def test_the_shell_runs_the_command_from_the_checkout(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- generated: test -f pyproject.toml && echo here -->\nx\n<!-- end generated -->\n")
    assert refresh_docs.refresh(doc, logs=None) == []
    assert "    test -f pyproject.toml && echo here\n\nhere\n" in doc.read_text()


@pytest.mark.parametrize("cmd", [m.group("cmd") for doc in sorted((ROOT / "docs").glob("*.md"))
                                 for m in refresh_docs.blocks(doc.read_text())])
def test_every_generated_table_names_a_benchmark_that_runs(cmd):
    """Each block's command is a benchmark script of this checkout whose options parse (its --help answers)."""
    words = shlex.split(cmd)
    scripts = [w for w in words if w.startswith("benchmarks/") and w.endswith(".py")]
    assert scripts and (ROOT / scripts[0]).is_file(), cmd
    p = subprocess.run(cmd + " --help", shell=True, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    i = words.index(scripts[0])
    options = [w.split("=")[0] for w in words[i + 1:] if w.startswith("--")]
    assert all(o in p.stdout for o in options), (options, p.stdout)
