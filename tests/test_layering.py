"""The layering the design keeps (DESIGN.md, Layout), read from the imports of every module: the
maths never imports SUMO or the run, the library never imports the runners, and no class grows
past a few hundred lines."""

import ast
from pathlib import Path

import pytest

from conftest import ROOT

PKG = ROOT / "nrtraffic"
PURE = ("control", "planning", "vehicle", "geometry")  # arrays in, arrays out
RUN = ("nrtraffic.engine", "nrtraffic.junction", "nrtraffic.lifecycle", "nrtraffic.state", "nrtraffic.measure",
       "nrtraffic.demand", "nrtraffic.results")


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
    return out


def _modules():
    return sorted(PKG.rglob("*.py"))


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_the_library_never_imports_the_runners(path):
    if path == PKG / "__init__.py":  # the package's top level hands out the runners' Python API, when first used
        return
    assert not {m for m in _imports(path) if m == "runners" or m.startswith("runners.")}


def test_the_python_api_is_imported_only_when_used():
    """``import nrtraffic`` loads neither the runners nor SUMO, pandas or Dask; ``nrtraffic.run``
    is ``runners.api.run``."""
    import subprocess
    import sys

    code = ("import sys, nrtraffic; heavy = [m for m in ('runners', 'runners.api', 'libsumo', 'traci', 'pandas', "
            "'dask', 'matplotlib') if m in sys.modules]; print(heavy); import runners.api; "
            "print(nrtraffic.run is runners.api.run and nrtraffic.Run is runners.api.Run)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True,
                         env={**__import__("os").environ, "PYTHONPATH": str(ROOT)}).stdout.split("\n")
    assert out[:2] == ["[]", "True"]


@pytest.mark.parametrize("path", [p for p in _modules() if p.relative_to(PKG).parts[0].removesuffix(".py") in PURE],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_the_maths_imports_neither_sumo_nor_the_run(path):
    bad = {m for m in _imports(path)
           if m.split(".")[0] in ("libsumo", "traci", "sumolib") or m.startswith("nrtraffic.sumo")
           or any(m == r or m.startswith(r + ".") for r in RUN)}
    assert not bad


def test_only_the_sumo_package_imports_sumo():
    for path in _modules():
        if path.relative_to(PKG).parts[0] == "sumo":
            continue
        assert not {m for m in _imports(path) if m.split(".")[0] in ("libsumo", "traci", "sumolib")}, path


def test_no_class_is_longer_than_about_400_lines():
    long = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > 420:
                long.append(f"{path.relative_to(ROOT)}:{node.name}")
    assert not long
