"""The package's shape, read from its own source: imports go one way through the flow's stages and form no cycle,
modules stay small, the top level stays short.

Every import counts, at module level and inside functions alike: an import deferred to keep start-up fast is still a
dependency, and a cycle hidden in a function is still a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG_DIR = Path(__file__).resolve().parents[1] / "bowsynth"

# The stages, lowest first, as the data flows: a Scene and the physics (with what a listener hears of a signal, the
# measures every later stage scores with) -> files in and out -> the engines -> the decisions a render makes from what
# ships (model, windows, tuning) and the music built on them -> training -> analysis against the reference -> the
# uses of it all (sound matching, live play) -> reports -> the Python API -> the CLI. A module may import its own
# stage or a lower one, never a higher one.
STAGES = [
    ("core", {"bowsynth", "bowsynth.errors", "bowsynth.physics", "bowsynth.controls", "bowsynth.scene",
              "bowsynth.render", "bowsynth.compiled", "bowsynth.metrics"}),
    ("io", {"bowsynth.io"}),
    ("engines", {"bowsynth.engines"}),
    ("decisions", {"bowsynth.music"}),
    ("training", {"bowsynth.training"}),
    ("analysis", {"bowsynth.analysis"}),
    ("uses", {"bowsynth.live", "bowsynth.fit"}),
    ("report", {"bowsynth.report"}),
    ("api", {"bowsynth.api", "bowsynth.corpus"}),
    ("cli", {"bowsynth.cli", "bowsynth.__main__"}),
]
MAX_LINES = 400
MAX_TOP_MODULES = 10


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG_DIR.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in PKG_DIR.rglob("*.py")}


def stage(mod: str) -> int:
    best = None
    for i, (_, roots) in enumerate(STAGES):
        for r in roots:
            if (mod == r or mod.startswith(r + ".")) and (best is None or len(r) > best[1]):
                best = (i, len(r))
    if best is None:
        raise AssertionError(f"{mod} belongs to no stage: add it to STAGES in tests/test_layout.py")
    return best[0]


def imports_of(mod: str, path: Path, known: set[str]) -> set[str]:
    """The package's own modules that `mod` imports, anywhere in its source."""
    base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                target = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target != "bowsynth" and not target.startswith("bowsynth."):
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                out.add(sub if sub in known else target)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "bowsynth"}
    # importing a.b.c runs a and a.b first: the parents' __init__ count as imported too
    for m in list(out):
        parts = m.split(".")
        out |= {".".join(parts[:i]) for i in range(1, len(parts)) if ".".join(parts[:i]) in known}
    return out - {mod}


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {m: imports_of(m, p, known) & known for m, p in mods.items()}


def test_imports_go_down_the_stages():
    upward = [f"{m} ({STAGES[stage(m)][0]}) imports {t} ({STAGES[stage(t)][0]})"
              for m, targets in graph().items() for t in sorted(targets)
              if stage(t) > stage(m) and not m.startswith(t + ".")]  # a package's parents run first, not imported
    assert not upward, "\n".join(upward)


def _cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    # a package importing its own submodules (its __init__ re-exporting them) is not a cycle the reader has to untie
    g = {m: {t for t in ts if not t.startswith(m + ".") and not m.startswith(t + ".")} for m, ts in graph().items()}
    assert _cycles(g) == []


def test_cycle_finder_finds_one():
    # the checker itself: a planted cycle a -> b -> c -> a and a clean chain
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": {"c"}}) == []


def test_stage_of_unknown_module_is_an_error():
    with pytest.raises(AssertionError, match="no stage"):
        stage("elsewhere.thing")
    assert stage("bowsynth.engines.operator.rollout") > stage("bowsynth.io.audio") > stage("bowsynth.scene")


def code_lines(path: Path) -> int:
    """The module's lines outside its docstrings: its documentation (numpydoc, examples) may be as long as it needs."""
    text, doc = path.read_text(), set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                    and isinstance(first.value.value, str)):
                doc.update(range(first.lineno, first.end_lineno + 1))
    return len(text.splitlines()) - len(doc)


@pytest.mark.parametrize("name", sorted(modules()))
def test_module_is_small(name):
    n = code_lines(modules()[name])
    assert n <= MAX_LINES, f"{name} has {n} lines of code (at most {MAX_LINES}): it holds more than one concept"


def test_docstrings_do_not_count_as_code(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""One.\n\nTwo."""\n\n\ndef g():\n    """Doc.\n\n    >>> g()\n    """\n    return 1\n')
    assert code_lines(f) == 11 - 3 - 4


def test_top_level_is_short():
    top = sorted(p.name for p in PKG_DIR.glob("*.py"))
    assert len(top) <= MAX_TOP_MODULES, top


def test_missing_numbers_are_written_one_way():
    import math

    from bowsynth.io.text import jsonable, num

    assert num(None) == num(float("nan")) == num(math.inf) == "n/a"
    assert num(0.000123, ".2e") == "1.23e-04" and num(3.14159, "{:.3g}") == "3.14"
    np = pytest.importorskip("numpy")
    out = jsonable({"a": [1.0, float("nan")], "b": (np.float32(2.5), -math.inf), "c": np.int64(3)})
    assert out == {"a": [1.0, None], "b": [2.5, None], "c": 3}
    assert isinstance(out["c"], int) and isinstance(out["b"][0], float)


def test_played_is_typed_and_reads_as_before():
    from bowsynth.render import Played

    p = Played("operator", fdm_fallback=True).with_fdm_release()
    assert p == "operator+fdm + fdm release" and p.engine == "operator" and p.fdm_fallback and p.fdm_release
    assert Played("fdm", 4) == "fdm x4" and Played("fdm", 4).oversample == 4 and not Played("fdm").fdm_release
    with pytest.raises(ValueError):
        Played("telepathy")
    import pickle  # a render travels between processes (a Ray task, a worker pool): every kind comes back itself

    for p in (Played("operator"), Played("operator", fdm_fallback=True), Played("fdm", 4),
              Played("operator", fdm_release=True)):
        q = pickle.loads(pickle.dumps(p))
        assert type(q) is Played and q == p
        assert (q.engine, q.oversample, q.fdm_fallback, q.fdm_release) == (p.engine, p.oversample, p.fdm_fallback,
                                                                          p.fdm_release)


def test_no_private_name_is_imported_from_another_module():
    """What a module shares it names without a leading underscore; the compiled extension (_core) is the one
    private module imported, by bowsynth.compiled alone."""
    found = []
    for mod, path in modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("bowsynth")):
                found += [f"{mod}: from {'.' * node.level}{node.module or ''} import {a.name}" for a in node.names
                          if a.name.startswith("_") and not a.name.startswith("__")
                          and not (mod == "bowsynth.compiled" and a.name == "_core")]
    assert not found, "\n".join(found)
