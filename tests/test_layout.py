"""The house's rules (docs/architecture.md): the layers in :data:`LAYERS` order, each importing only
from the layers before it; no import cycle between modules; no module (or test file) over 400 lines,
no line over 120 characters. Every import counts: at a module's top level and inside its functions
(``ast.walk``), absolute and relative."""

from __future__ import annotations

import ast
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 400
MAX_COLUMNS = 120  # the hard limit (the formatter wraps at 100; ruff's E501 holds 120 in CI)

# docs/architecture.md's layers, lowest first: a module imports only from its own layer and those
# before it. The root package (``layercam/__init__.py``) and ``layercam.configs`` (the presets'
# TOML files) sit with core; ``layercam.cli`` and ``layercam.__main__`` with the commands.
LAYERS = ("core", "io", "vision", "scene", "camera", "engine", "pipelines", "synth", "bench", "commands")
_LAYER_OF = {"layercam": "core", "configs": "core", "cli": "commands", "__main__": "commands"}


def _modules() -> dict[str, Path]:
    """Every module of the package, by dotted name (``pipelines/`` and ``configs/`` install as
    ``layercam.pipelines`` and ``layercam.configs``)."""
    out = {}
    for top in ("layercam", "pipelines", "configs"):
        for p in sorted((ROOT / top).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            parts = ["layercam"] + parts if parts[0] != "layercam" else parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _imports(name: str, path: Path, known: dict) -> dict[str, int]:
    """The layercam modules ``name`` (at ``path``) imports anywhere in it, each with the line of its
    first import: ``import a.b``, ``from a import b`` (``a.b`` when it is a module, else ``a``) and
    relative imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: dict[str, int] = {}
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.Import):
            targets = [a.name for a in n.names]
        elif isinstance(n, ast.ImportFrom):
            base = n.module or ""
            if n.level:
                up = package.split(".")[: len(package.split(".")) - (n.level - 1)]
                base = ".".join(up + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in n.names]
        else:
            continue
        for t in targets:
            while t and t not in known and "." in t:  # import a.b.c of a package a.b: the deepest module known
                t = t.rpartition(".")[0]
            if t in known and t != name:
                out.setdefault(t, n.lineno)
    return out


def _graph() -> dict[str, dict[str, int]]:
    mods = _modules()
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def layer(module: str) -> str:
    """The layer of a dotted module name (``layercam.scene.render`` -> ``scene``)."""
    parts = module.split(".")
    top = parts[1] if len(parts) > 1 else parts[0]
    found = _LAYER_OF.get(top, top)
    assert found in LAYERS, f"{module}: not in any layer of LAYERS (docs/architecture.md)"
    return found


def cycles(graph: dict[str, dict]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def upward(graph: dict[str, dict]) -> list[str]:
    """Every import of a module from a layer after its own: ``a (line) -> b``."""
    rank = {name: i for i, name in enumerate(LAYERS)}
    return [f"{a}:{line} -> {b}" for a in sorted(graph) for b,
            line in sorted(graph[a].items()) if rank[layer(b)] > rank[layer(a)]]


def test_the_import_reader_sees_every_import(tmp_path):
    """Imports inside functions and relative ones count as the top level's do."""
    pkg = tmp_path / "layercam" / "scene"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg
     / "a.py").write_text("def f():\n    from . import b\n    from layercam.engine import train\n  "
                          "  import layercam.scene.b\n")
    known = {"layercam.scene.a": 0, "layercam.scene.b": 0, "layercam.engine.train": 0, "layercam.engine": 0}
    assert set(_imports("layercam.scene.a", pkg / "a.py", known)) == {"layercam.scene.b", "layercam.engine.train"}
    graph = {"layercam.scene.a": {"layercam.engine.train": 3}, "layercam.engine.train": {"layercam.scene.a": 1}}
    assert cycles(graph) == [["layercam.engine.train", "layercam.scene.a"]]
    assert upward(graph) == ["layercam.scene.a:3 -> layercam.engine.train"]


def test_layers_are_those_of_the_architecture():
    """Every package of layercam is a layer, and docs/architecture.md states them in this order."""
    assert {layer(m) for m in _modules()} == set(LAYERS)
    assert " < ".join(LAYERS) in (ROOT / "docs" / "architecture.md").read_text()


def test_no_import_cycles():
    found = cycles(_graph())
    assert not found, "import cycles (every import, in functions too):\n" + "\n".join(" <-> ".join(c) for c in found)


def test_no_upward_imports():
    found = upward(_graph())
    assert not found, "imports from a later layer (LAYERS, docs/architecture.md):\n" + "\n".join(found)


def _sources() -> list[Path]:
    return list(_modules().values()) + sorted((ROOT / "tests").rglob("*.py"))


def test_no_module_over_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in _sources() if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"split these modules: {long}"


def test_no_line_over_120_characters():
    wide = [f"{p.relative_to(ROOT)}:{i}" for p in _sources() for i,
            s in enumerate(p.read_text().splitlines(), 1) if len(s) > MAX_COLUMNS]
    assert not wide, f"{len(wide)} lines over {MAX_COLUMNS} characters, e.g. {wide[:5]}"


def test_every_package_is_installed():
    """A non-editable install holds every package folder (pyproject.toml lists them)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "layercam").rglob("__init__.py")}
    found |= {"layercam." + ".".join(p.parent.relative_to(ROOT).parts)
              for p in (ROOT / "pipelines").rglob("__init__.py")}
    assert found - listed == set(), f"add to pyproject.toml's packages: {sorted(found - listed)}"
