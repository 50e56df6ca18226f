"""The public API's docstrings: their examples run (doctest), and the API reference builds from them (pdoc, as `make
docs` builds it). The documented modules are listed once, in the Makefile's DOC_MODULES."""

from __future__ import annotations

import doctest
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def doc_modules() -> list[str]:
    """The modules `make docs` documents: the Makefile's DOC_MODULES line."""
    m = re.search(r"^DOC_MODULES\s*:=\s*(.+)$", (ROOT / "Makefile").read_text(), re.M)
    assert m, "the Makefile has no DOC_MODULES := ... line"
    return m.group(1).split()


def test_doc_modules_are_listed():
    mods = doc_modules()
    assert {"bowsynth.api", "bowsynth.scene", "bowsynth.render"} <= set(mods)
    assert len(mods) == len(set(mods))


@pytest.mark.parametrize("name", doc_modules())
def test_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write a file (a score, a MIDI file) write it here
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (output above)"


def test_api_reference_builds(tmp_path):
    out = tmp_path / "api"
    run = subprocess.run([sys.executable, "-m", "pdoc", "--docformat", "numpy", "-o", str(out), *doc_modules()],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr
    page = (out / "bowsynth" / "api.html").read_text()
    for name in ("render", "render_fdm", "render_operator", "tuning_for", "fit", "load_model", "model_path", "train"):
        assert f'id="{name}"' in page, name
    assert ">Parameters<" in page and ">Examples<" in page
    for name in doc_modules():
        assert (out / Path(*name.split("."))).with_suffix(".html").is_file(), name
