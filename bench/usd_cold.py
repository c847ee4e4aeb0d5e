"""A cold first image, broken down: `python -m bench.usd_cold RENDER-ARGS...` runs
`asset-preview render RENDER-ARGS` in this (new) process and prints, as the last line of
stdout, a JSON object of seconds per phase:

- python: interpreter start to this module's first line (from the process's start time)
- pxr_import: importing the pxr modules the stage reader imports first (Sdf, Usd, UsdGeom,
  UsdShade, UsdUtils; UsdLux and UsdSkel come later, with a stage's first light or skeleton)
- our_import: the CLI's own imports (numpy, moderngl, pipeline, renderer ...) and argument
  parsing, up to its first bake_asset call; a module imported later counts in the phase
  that imports it (the stage reader's in bake, as before)
- composition: the layers read (LayerGraph.open) and composed (Usd.Stage.Open)
- materialx: MaterialX's library, documents and surfaces read
- bake: the rest of bake_asset (meshes, textures, interior, cache write)
- environment: bake_environment
- first_frame: render() (GL context, upload, shaders, draw, read back)
- other: what is left of the time to exit (argument parsing, encoding the PNG ...)

"cpu" holds the same phases in CPU seconds (all threads), steadier than wall time on a loaded machine.

Each phase's time is exclusive: a MaterialX read inside the bake counts once, as MaterialX.
The timers are put on the modules as the command imports them, so this script imports
nothing of ours that a cold `render` would not.
"""
from __future__ import annotations

import functools
import importlib.machinery
import json
import os
import runpy
import sys
import time

_T0 = time.perf_counter()


def _process_age() -> float:
    """Seconds since this process started (/proc: start time in clock ticks after boot)."""
    with open("/proc/self/stat") as f:
        start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as f:
        uptime = float(f.read().split()[0])
    return uptime - start_ticks / os.sysconf("SC_CLK_TCK")


class _Phases:
    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.cpu: dict[str, float] = {}  # the same, in CPU seconds (all threads)
        self._stack: list[list] = []  # [phase, started, cpu started, seconds, cpu s of nested phases]

    def wrap(self, owner, name: str, phase: str, static: bool = False) -> None:
        fn = getattr(owner, name)

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            self._stack.append([phase, time.perf_counter(), time.process_time(), 0.0, 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                ph, start, cpu_start, inner, cpu_inner = self._stack.pop()
                spent, cpu = time.perf_counter() - start, time.process_time() - cpu_start
                self.seconds[ph] = self.seconds.get(ph, 0.0) + spent - inner
                self.cpu[ph] = self.cpu.get(ph, 0.0) + cpu - cpu_inner
                if self._stack:
                    self._stack[-1][3] += spent
                    self._stack[-1][4] += cpu
        setattr(owner, name, staticmethod(timed) if static else timed)


class _OnImport:
    """A meta path finder that runs `hooks[name](module)` once module `name` has executed."""

    def __init__(self, hooks: dict) -> None:
        self.hooks = hooks

    def find_spec(self, name, path=None, target=None):
        hook = self.hooks.pop(name, None)
        if hook is None:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            run = spec.loader.exec_module

            def exec_module(module) -> None:
                run(module)
                hook(module)
            spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


def main(argv: list[str]) -> int:
    python_s = max(_process_age() - (time.perf_counter() - _T0), 0.0)
    phases = _Phases()
    cpu = {"python": time.process_time()}
    t = time.perf_counter()
    from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdUtils  # noqa: F401
    pxr_s = time.perf_counter() - t
    cpu["pxr_import"] = time.process_time() - cpu["python"]
    phases.wrap(Usd.Stage, "Open", "composition", static=True)

    ours: dict[str, float] = {}  # our_import: the run's start to its first bake_asset call

    def bake(m) -> None:
        phases.wrap(m, "bake_asset", "bake")
        phases.wrap(m, "bake_environment", "environment")
        timed = m.bake_asset

        @functools.wraps(timed)
        def first(*args, **kwargs):
            if not ours:
                ours.update(wall=time.perf_counter(), cpu=time.process_time())
            return timed(*args, **kwargs)
        m.bake_asset = first

    def materialx(m) -> None:
        for fn in ("library", "read_document", "find_references"):
            phases.wrap(m, fn, "materialx")
    sys.meta_path.insert(0, _OnImport({
        "pipeline.bake": bake,
        "pipeline.usd.layers": lambda m: phases.wrap(m.LayerGraph, "open", "composition"),
        "pipeline.usd.materialx": materialx,
        "pipeline.usd.materials": lambda m: phases.wrap(m.MaterialReader, "_materialx", "materialx"),
        "renderer.raster.render": lambda m: phases.wrap(m, "render", "first_frame")}))
    cpu_run = cpu_start = time.process_time()
    t = time.perf_counter()
    # The command line runs as `python -m cli.main` would (bench sits below cli in the layers,
    # so it runs the entry point rather than importing it).
    sys.argv = ["asset-preview", "render", *argv]
    try:
        runpy.run_module("cli.main", run_name="__main__", alter_sys=True)
        rc = 0
    except SystemExit as e:
        rc = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    run_s = time.perf_counter() - t
    cpu_run = time.process_time() - cpu_run
    ours_s, ours_cpu = (ours["wall"] - t, ours["cpu"] - cpu_start) if ours else (0.0, 0.0)
    run_s, cpu_run = run_s - ours_s, cpu_run - ours_cpu
    cpu["our_import"] = ours_cpu
    out: dict[str, object] = {"python": python_s, "pxr_import": pxr_s, "our_import": ours_s,
           **{k: phases.seconds.get(k, 0.0) for k in
              ("composition", "materialx", "bake", "environment", "first_frame")}}
    out["other"] = max(run_s - sum(phases.seconds.values()), 0.0)
    cpu.update({k: phases.cpu.get(k, 0.0) for k in ("composition", "materialx", "bake", "environment", "first_frame")})
    cpu["other"] = max(cpu_run - sum(phases.cpu.values()), 0.0)
    out["cpu"] = cpu  # CPU seconds per phase, as `out`'s wall seconds
    out["rc"] = rc
    out["cpu_s"] = time.process_time()  # all threads, since the process started: less load-bound than wall time
    sys.stdout.flush()
    print(json.dumps(out))
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
