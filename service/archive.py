"""Safe extraction of uploaded .zip archives (a .gltf with its files, a USD with its layers).

Refused before anything is written: absolute paths, drive letters, `..` escapes, symbolic
links and other non-regular entries, more than `max_files` entries, and a declared total
beyond `max_bytes`. Sizes declared in the central directory can lie, so the bytes actually
inflated are counted too and extraction stops at the bound.
"""
from __future__ import annotations

import stat
import zipfile
from pathlib import Path, PurePosixPath

from core.errors import LimitExceeded, MalformedAsset, UnsafeReference
from pipeline.ingest import READERS

ROOT_SUFFIXES = tuple(READERS)
SCENE_SUFFIXES = tuple(s for s, kind in READERS.items() if kind != "mesh")  # glTF and USD
_CHUNK = 1 << 16


def extract(archive: Path, dest: Path, *, max_bytes: int, max_files: int, label: str = "") -> list[str]:
    """Extract `archive` into the (new, empty) folder `dest`; returns the member paths written."""
    name = label or archive.name
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError) as exc:
        raise MalformedAsset(name, f"not a readable zip archive ({exc})") from None
    with zf:
        members = [m for m in zf.infolist() if not m.is_dir()]
        if len(members) > max_files:
            raise LimitExceeded(name, f"archive holds {len(members)} files, more than the limit "
                                      f"of {max_files}")
        declared = sum(m.file_size for m in members)
        if declared > max_bytes:
            raise LimitExceeded(name, f"archive unpacks to {declared} bytes, more than the limit "
                                      f"of {max_bytes} bytes")
        targets = [(_safe_member(m, name), m) for m in members]
        dest.mkdir(parents=True, exist_ok=True)
        written, total = [], 0
        for rel, info in targets:
            out = dest.joinpath(*rel.parts)
            out.parent.mkdir(parents=True, exist_ok=True)
            try:
                with zf.open(info) as src, open(out, "xb") as dst:
                    while chunk := src.read(_CHUNK):
                        total += len(chunk)
                        if total > max_bytes:
                            raise LimitExceeded(name, f"archive inflates past the limit of "
                                                      f"{max_bytes} bytes")
                        dst.write(chunk)
            except FileExistsError:
                raise MalformedAsset(name, f"archive holds {info.filename!r} twice") from None
            except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError) as exc:
                raise MalformedAsset(name, f"cannot inflate {info.filename!r} ({exc})") from None
            written.append(rel.as_posix())
        return written


def _safe_member(info: zipfile.ZipInfo, name: str) -> PurePosixPath:
    raw = info.filename
    mode = info.external_attr >> 16
    if mode and (stat.S_ISLNK(mode) or not (stat.S_ISREG(mode) or stat.S_IFMT(mode) == 0)):
        raise UnsafeReference(name, f"archive entry {raw!r} is a link or special file; only "
                                    "regular files are accepted")
    text = raw.replace("\\", "/")
    if "\x00" in text:
        raise UnsafeReference(name, f"archive entry {raw!r} has a NUL byte in its name")
    path = PurePosixPath(text)
    if text.startswith("/") or path.is_absolute() or (len(text) > 1 and text[1] == ":"):
        raise UnsafeReference(name, f"archive entry {raw!r} is an absolute path")
    if any(part == ".." for part in path.parts):
        raise UnsafeReference(name, f"archive entry {raw!r} escapes the archive's folder")
    parts = [p for p in path.parts if p not in ("", ".")]
    if not parts:
        raise MalformedAsset(name, f"archive entry {raw!r} has no file name")
    return PurePosixPath(*parts)


def find_root(files: list[str], name: str, main: str | None = None) -> str:
    """The asset file to ingest among extracted `files`: `main` when given, else the only
    supported file at the shallowest depth, else the one whose stem matches the archive's."""
    if main:
        wanted = PurePosixPath(main.replace("\\", "/")).as_posix().lstrip("./")
        if wanted not in files:
            raise MalformedAsset(name, f"main file {main!r} is not in the archive")
        return wanted
    candidates = [f for f in files if f.lower().endswith(ROOT_SUFFIXES) and "__MACOSX" not in f]
    if not candidates:
        raise MalformedAsset(name, "archive holds no .gltf, .glb or USD file")
    depth = min(f.count("/") for f in candidates)
    top = sorted(f for f in candidates if f.count("/") == depth)
    # A .gltf's sidecar .bin never competes; prefer scene files over plain meshes.
    scenes = [f for f in top if f.lower().endswith(SCENE_SUFFIXES)]
    top = scenes or top
    if len(top) == 1:
        return top[0]
    stem = PurePosixPath(name).stem.lower()
    named = [f for f in top if PurePosixPath(f).stem.lower() == stem]
    if len(named) == 1:
        return named[0]
    raise MalformedAsset(name, f"archive holds several asset files ({', '.join(top[:8])}); "
                               "name the one to use in the `main` form field")
