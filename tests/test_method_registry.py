"""The one registry of render methods (renderer/methods/registry.py): every method a request
may name is there, an unknown one is refused naming those that exist, the method modules are
plain imports (no importlib) that never import the frame orchestration back, and the
renderer's modules, counted with their package `__init__`s, import no cycle."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from core.options import RenderOptions
from renderer.methods import refraction, registry
from renderer.raster import render as orchestration

ROOT = Path(__file__).resolve().parents[1]


def test_every_method_is_registered_once():
    assert registry.available_methods() == ["auto", "opaque", "single", "wyman", "raytrace"]
    assert registry.METHODS == {"single": refraction.draw_single, "wyman": refraction.draw_wyman}
    assert registry.FRAME_METHODS == {"raytrace": registry.render_raytrace}
    for name in registry.available_methods():
        registry.validate_options(RenderOptions(method=name))


def test_a_raster_render_does_not_import_the_tracer():
    """The registry's raytrace entry imports renderer.methods.raytrace when a frame is traced
    (tests/test_raytrace*.py trace through it)."""
    code = ("import sys, renderer.raster.render; "
            "assert 'renderer.methods.raytrace' not in sys.modules, 'the raster path imports the tracer'")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_an_unregistered_method_is_refused_by_name():
    options = RenderOptions()
    object.__setattr__(options, "method", "bogus")  # past the schema, as a stale client's would be
    with pytest.raises(registry.UnsupportedMethod, match="'bogus'.*auto, opaque, single, wyman, raytrace"):
        orchestration.validate_options(options)


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def _modules() -> dict[str, Path]:
    mods = {}
    for path in (ROOT / "renderer").rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


def test_no_importlib_and_no_method_imports_the_orchestration():
    for name, path in _modules().items():
        assert "importlib" not in _imports(path), f"{name} loads modules through importlib"
        if name.startswith("renderer.methods") or name.startswith("renderer.raster."):
            assert "renderer.raster.render" not in _imports(path) or name == "renderer.raster.render", name


def test_no_cycle_counting_package_inits():
    """A module that imports `renderer.x.y` runs `renderer/__init__` and `renderer/x/__init__`
    first: those count as its imports, and nothing the package inits import may import back."""
    mods = _modules()
    edges: dict[str, set[str]] = {}
    for name, path in mods.items():
        targets = set()
        for imported in _imports(path):
            targets.add(imported)  # named: counts even when it is the module's own package
            parts = imported.split(".")
            targets |= {".".join(parts[:i]) for i in range(1, len(parts))
                        if not name.startswith(".".join(parts[:i]) + ".")}  # run first anyway
        edges[name] = (targets & set(mods)) - {name}
    seen: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(v: str, path: list[str]) -> None:
        seen[v] = 1
        for w in sorted(edges[v]):
            assert seen.get(w) != 1, " -> ".join(path + [w])
            if w not in seen:
                visit(w, path + [w])
        seen[v] = 2
    for v in sorted(mods):
        if v not in seen:
            visit(v, [v])
