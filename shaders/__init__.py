"""GLSL sources shipped as package data. `load` resolves `#include "file"` and injects defines."""
from __future__ import annotations

import re
from functools import lru_cache
from importlib import resources

_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.M)


@lru_cache(maxsize=None)
def _read(name: str) -> str:
    return resources.files(__name__).joinpath(name).read_text()


def _expand(name: str, seen: tuple[str, ...]) -> str:
    if name in seen:
        raise ValueError(f"shader include cycle: {' -> '.join(seen + (name,))}")
    return _INCLUDE.sub(lambda m: _expand(m.group(1), seen + (name,)), _read(name))


def load(name: str, defines: dict | None = None) -> str:
    """Source of shader `name` with includes expanded and `#define K V` lines after #version."""
    src = _expand(name, ())
    if defines:
        lines = "".join(f"#define {k} {v}\n" for k, v in sorted(defines.items()))
        head, sep, rest = src.partition("\n")
        if not head.startswith("#version"):
            raise ValueError(f"shader {name} must start with #version")
        src = head + sep + lines + rest
    return src
