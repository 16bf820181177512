"""The examples in the package's docstrings run and hold (``>>>`` lines are doctests)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import layercam

MODULES = sorted(m.name for m in pkgutil.walk_packages(layercam.__path__, "layercam.")
                 if not m.name.endswith("__main__"))


def _with_examples() -> list[str]:
    out = []
    for name in MODULES:
        if any(t.examples for t in doctest.DocTestFinder().find(importlib.import_module(name))):
            out.append(name)
    return out


WITH_EXAMPLES = _with_examples()


def test_the_examples_are_found():
    assert {"layercam.core.presets", "layercam.core.geometry", "layercam.core.colour",
            "layercam.camera.blur", "layercam.bench.viz"} <= set(WITH_EXAMPLES)


@pytest.mark.parametrize("name", WITH_EXAMPLES)
def test_docstring_examples(name):
    res = doctest.testmod(importlib.import_module(name),
                          optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                          verbose=False)
    assert res.failed == 0, f"{res.failed} of {res.attempted} examples failed in {name}"
