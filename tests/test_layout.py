"""The house's rules (docs/architecture.md): no module (or test file) over 400 lines, no import cycle between
modules (imports at a module's top level), and ``layercam.core`` imports nothing else of layercam."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 400


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted((ROOT / "layercam").rglob("*.py")) + sorted((ROOT / "pipelines").rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        parts = ["layercam"] + parts if parts[0] == "pipelines" else parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _imports(path: Path, known: dict) -> set[str]:
    """The layercam modules ``path`` imports at its top level."""
    out = set()
    for n in ast.parse(path.read_text()).body:
        if isinstance(n, ast.ImportFrom) and n.module and n.module.startswith("layercam"):
            out |= {f"{n.module}.{a.name}" if f"{n.module}.{a.name}" in known else n.module for a in n.names}
        elif isinstance(n, ast.Import):
            out |= {a.name for a in n.names if a.name.startswith("layercam")}
    return {m for m in out if m in known}


def test_no_module_over_400_lines():
    files = list(_modules().values()) + sorted((ROOT / "tests").rglob("*.py"))
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"split these modules: {long}"


def test_no_import_cycles():
    mods = _modules()
    graph = {m: _imports(p, mods) - {m} for m, p in mods.items()}
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(m, path):
        state[m] = 1
        for d in sorted(graph[m]):
            assert state.get(d) != 1, "import cycle: " + " -> ".join(path + [m, d])
            if d not in state:
                visit(d, path + [m])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])


def test_core_imports_only_core():
    mods = _modules()
    for m, p in mods.items():
        if m.startswith("layercam.core"):
            outside = {d for d in _imports(p, mods) if not d.startswith("layercam.core")}
            assert not outside, f"{m} imports {outside}"


def test_every_package_is_installed():
    """A non-editable install holds every package folder (pyproject.toml lists them)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "layercam").rglob("__init__.py")}
    assert found - listed == set(), f"add to pyproject.toml's packages: {sorted(found - listed)}"
