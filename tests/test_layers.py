"""The architecture, asserted: layers imported only downward, no import cycles between modules,
no private names reached into across modules (DESIGN.md, "Layers").

core      plain data and conventions (scene, baked types, render options, errors, cubemap and
          colour conventions): imports nothing of ours but itself and shaders
gl        the headless GL context and its programs -> shaders
pipeline  ingest, bake, cache                      -> core, gl (environment prefiltering)
renderer  GL passes and methods, from baked data   -> core, gl (never pipeline: no source files)
service   HTTP, workers                            -> core, gl, pipeline, renderer
cli       the command lines                        -> everything
bench     benchmarks                               -> everything but cli
Every import counts, at module level or inside a function, and so do the package inits it
runs (importing `pipeline.bake` first imports `pipeline`) and `importlib.import_module` calls
with a literal name.
"""
import ast
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OURS = ("core", "gl", "pipeline", "renderer", "service", "cli", "bench", "shaders")
ALLOWED = {
    "core": {"core", "shaders"},
    "gl": {"gl", "shaders"},
    "pipeline": {"core", "gl", "pipeline", "shaders"},
    "renderer": {"core", "gl", "renderer", "shaders"},
    "service": {"core", "gl", "pipeline", "renderer", "service"},
    "cli": {"core", "gl", "pipeline", "renderer", "service", "cli", "bench"},
    "bench": {"core", "gl", "pipeline", "renderer", "service", "bench", "shaders"},
    "shaders": {"shaders"},
}


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in OURS:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            mods[name] = path
    return mods


def _imports(name: str, path: Path, mods: dict[str, Path]):
    """(imported module, names taken from it, line) for every import of ours in a module."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call) and _is_import_module(node):
            target = node.args[0].value
            if target.split(".")[0] in OURS:
                yield target, [], node.lineno
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in OURS:
                    yield a.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] not in OURS:
                continue
            plain = []
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in mods:  # `from pkg import module`
                    yield sub, [], node.lineno
                else:
                    plain.append(a.name)
            if plain or target in mods:
                yield target, plain, node.lineno


def _is_import_module(node: ast.Call) -> bool:
    """`importlib.import_module("literal")` or `import_module("literal")`."""
    f = node.func
    named = (isinstance(f, ast.Attribute) and f.attr == "import_module"
             and isinstance(f.value, ast.Name) and f.value.id == "importlib") or \
        (isinstance(f, ast.Name) and f.id == "import_module")
    return named and bool(node.args) and isinstance(node.args[0], ast.Constant) \
        and isinstance(node.args[0].value, str)


def _with_packages(target: str, mods: dict[str, Path]) -> list[str]:
    """What importing `target` runs of ours: each enclosing package's init, then it."""
    parts = target.split(".")
    return [m for m in (".".join(parts[:k]) for k in range(1, len(parts) + 1)) if m in mods]


@lru_cache(maxsize=1)
def _graph():
    mods = _modules()
    return mods, {n: list(_imports(n, p, mods)) for n, p in mods.items()}


def test_layers_are_imported_only_downward():
    mods, graph = _graph()
    bad = [f"{mods[n].relative_to(ROOT)}:{line} imports {t}"
           for n, edges in graph.items() for t, _, line in edges
           if t.split(".")[0] not in ALLOWED[n.split(".")[0]]]
    assert not bad, "\n".join(bad)


def test_no_private_names_across_modules():
    mods, graph = _graph()
    bad = [f"{mods[n].relative_to(ROOT)}:{line} takes {t}.{x}"
           for n, edges in graph.items() for t, names, line in edges if t != n
           for x in names if x.startswith("_") and not x.startswith("__")]
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    mods, graph = _graph()
    edges = {n: sorted({m for t, _, _ in es for m in _with_packages(t, mods) if m != n})
             for n, es in graph.items()}
    # Tarjan's strongly connected components: any component of two or more is a cycle.
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
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
                cycles.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    # Known, being removed on the renderer side of issue 24: `renderer/__init__` imports
    # `renderer.raster.render`, whose modules import `renderer.*` back. Drop this once it is gone.
    cycles = [c for c in cycles if not (c[0] == "renderer" and all(m.startswith("renderer.")
                                                                   for m in c[1:]))]
    assert not cycles, cycles
