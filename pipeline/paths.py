"""Resolving file references found inside an asset, refusing anything unsafe.

Untrusted input may only read files inside its sandbox root: no network, no absolute paths,
no `..` escapes, no symlinks that lead out. The root is one rule for every format
(`sandbox_root`): the asset's own folder by default (the library call); the service passes the
upload (or unpacked zip) folder, always. Files a user names on the command line are trusted as
usdview, Blender and f3d trust them: the CLI passes `UNCONFINED` (any local file, absolute
paths included; still no URLs: nothing is downloaded), or the folder of `--sandbox DIR`.
`data:` URIs are not paths; the glTF reader decodes them before it would call this.
"""
from __future__ import annotations

import re
from pathlib import Path, PurePosixPath
from urllib.parse import unquote

from core.errors import MissingFile, UnsafeReference

# "scheme:" per RFC 3986; a single letter is a Windows drive ("C:"), refused as absolute.
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.\-]*):")

# The root that holds every local path: a trusted local file reads its neighbours anywhere.
UNCONFINED = Path("/")


def sandbox_root(asset, root=None) -> Path:
    """The folder every file `asset` references must lie in: `root` when given (it must hold
    the asset), else the asset's own folder. Resolved (symlinks followed)."""
    real = Path(asset).resolve()
    if root is None:
        return real.parent
    top = Path(root).resolve()
    if not _inside(real, top):
        raise UnsafeReference(asset, f"the asset is outside the root {top}")
    return top


def resolve_reference(asset: Path, uri: str, base_dir: Path | None = None,
                      root: Path | None = None) -> Path:
    """The file `uri` (found inside `asset`) names, relative to `base_dir` (default the
    asset's folder), guaranteed to lie inside `sandbox_root(asset, root)`.

    Raises UnsafeReference for URLs of any scheme, absolute paths, and paths or symlinks that
    resolve outside the root (the message names it); MissingFile when the target does not exist.
    """
    asset = Path(asset)
    base = Path(base_dir) if base_dir is not None else asset.parent
    top_real = sandbox_root(asset, root)
    path_text = relative_path_text(asset, uri, absolute_ok=top_real == UNCONFINED)
    candidate = base / path_text
    # Lexical check first (catches `..` even when the target is missing), then the real one
    # (catches symlinks whose target lies outside).
    lexical = Path(_normalise(base.resolve() / path_text))
    if not _inside(lexical, top_real):
        raise UnsafeReference(asset, f"refusing reference {uri!r}: it leaves the root "
                                     f"{top_real}")
    real = candidate.resolve()
    if not _inside(real, top_real):
        raise UnsafeReference(asset, f"refusing reference {uri!r}: it resolves (through a "
                                     f"link) to {real}, outside the root {top_real}")
    if not real.is_file():
        raise MissingFile(asset, f"referenced file {uri!r} not found (looked at {candidate})")
    return real


def relative_path_text(asset, uri: str, absolute_ok: bool = False) -> str:
    """The relative path `uri` (found inside `asset`) spells, `/`-separated and unquoted.

    Raises UnsafeReference for an empty reference, a URL of any scheme, a NUL byte, a drive
    path and (unless `absolute_ok`: an unconfined local file) an absolute path. Where the path
    leads is the caller's to check (`resolve_reference` on disk, `usd_layers` inside a package)."""
    if not uri or not uri.strip():
        raise UnsafeReference(asset, "empty file reference")
    m = _SCHEME.match(uri)
    if m and len(m.group(1)) > 1:
        raise UnsafeReference(asset, f"refusing reference {uri!r}: {m.group(1)}: URIs are not "
                                     "followed (only relative file paths)")
    path_text = unquote(uri).replace("\\", "/")
    if "\x00" in path_text:
        raise UnsafeReference(asset, f"refusing reference {uri!r}: NUL byte in path")
    posix_absolute = path_text.startswith("/") or PurePosixPath(path_text).is_absolute()
    if (m and len(m.group(1)) == 1) or (posix_absolute and not absolute_ok):
        raise UnsafeReference(asset, f"refusing absolute path {uri!r}: references must be "
                                     "relative to the asset")
    return path_text


def _normalise(p: Path) -> str:
    parts: list[str] = []
    for part in p.parts:
        if part == "..":
            if len(parts) > 1:
                parts.pop()
        elif part != ".":
            parts.append(part)
    return str(Path(*parts)) if parts else str(p)


def _inside(p: Path, root: Path) -> bool:
    return p == root or root in p.parents
