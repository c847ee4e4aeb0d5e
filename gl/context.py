"""One headless OpenGL context per process (EGL, no display), and compiled programs kept in it.

Prefiltering (pipeline.environment.prefilter) and rendering share this context; programs are compiled
once per (shaders, defines) and reused.
"""
from __future__ import annotations

import ctypes
import functools
import logging
import os
import threading
import typing

import moderngl

import shaders

log = logging.getLogger(__name__)

_lock = threading.RLock()
_ctx: moderngl.Context | None = None
_pid: int | None = None
_programs: dict[tuple, moderngl.Program | moderngl.ComputeShader] = {}
_fullscreen: dict[int, moderngl.VertexArray] = {}


class ContextError(RuntimeError):
    """Headless OpenGL is not available (message says what to install)."""


@functools.lru_cache(maxsize=None)
def library(name: str) -> str | None:
    """What dlopen is given for lib`name` (GL, EGL): its usual soname when the loader finds it,
    else `ctypes.util.find_library`'s answer. glcontext asks find_library for both, which runs
    `ldconfig -p` in a subprocess each time: two forks of every cold start."""
    soname = f"lib{name}.so.1"
    try:
        ctypes.CDLL(soname)
    except OSError:
        from ctypes.util import find_library
        return find_library(name)
    return soname


def get_context() -> moderngl.Context:
    """The process's EGL context, created on first use (and anew in a forked child)."""
    global _ctx, _pid
    with _lock:
        if _ctx is None or _pid != os.getpid():
            try:
                # the stubs type the backend's keyword arguments as dicts; they are strings
                libs: dict = {"libgl": library("GL"), "libegl": library("EGL")}
                _ctx = moderngl.create_standalone_context(backend="egl", require=430, **libs)  # type: ignore[arg-type]
            except Exception as exc:  # moderngl raises plain Exception for EGL failures
                raise ContextError(
                    f"headless OpenGL 4.3 via EGL is not available ({exc}); install Mesa: "
                    "apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri") from exc
            _pid = os.getpid()
            _programs.clear()
            _fullscreen.clear()
            if log.isEnabledFor(logging.INFO):  # ctx.info queries every GL limit (1 ms)
                log.info("GL context: %s, OpenGL %s", _ctx.info["GL_RENDERER"], _ctx.version_code)
        return _ctx


def program(vertex: str, fragment: str | None = None, defines: dict | None = None) -> moderngl.Program:
    """Compile (once) a program from shader files in `shaders/` with `#define`s."""
    key = (vertex, fragment, tuple(sorted((defines or {}).items())))
    with _lock:
        ctx = get_context()
        prog = _programs.get(key)
        if prog is None:
            kwargs = {"vertex_shader": shaders.load(vertex, defines)}
            if fragment:
                kwargs["fragment_shader"] = shaders.load(fragment, defines)
            prog = ctx.program(**kwargs)  # type: ignore[arg-type]  # stubs: shader sources are str
            _programs[key] = prog
        return typing.cast(moderngl.Program, prog)


def compute(name: str, defines: dict | None = None) -> moderngl.ComputeShader:
    """Compile (once) a compute shader from `shaders/`."""
    key = ("compute", name, tuple(sorted((defines or {}).items())))
    with _lock:
        ctx = get_context()
        prog = _programs.get(key)
        if prog is None:
            prog = ctx.compute_shader(shaders.load(name, defines))
            _programs[key] = prog
        return typing.cast(moderngl.ComputeShader, prog)


def fullscreen_vao(prog: moderngl.Program) -> moderngl.VertexArray:
    """A vertex array drawing one triangle that covers the viewport (no vertex buffer:
    the vertex shader derives positions from gl_VertexID). Render with `vao.render(vertices=3)`."""
    with _lock:
        ctx = get_context()
        vao = _fullscreen.get(prog.glo)
        if vao is None:
            vao = ctx.vertex_array(prog, [])
            _fullscreen[prog.glo] = vao
        return vao
