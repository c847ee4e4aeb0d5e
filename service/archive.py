"""Safe extraction of uploaded .zip archives (a .gltf with its files, a USD with its layers).

Refused before anything is written: absolute paths, drive letters, `..` escapes, symbolic
links and other non-regular entries, encrypted members, compression methods zipfile cannot
inflate, a name used both as a file and as a folder, paths deeper than `max_depth` or with a
part longer than `max_name`, more than `max_files` entries, and a declared total beyond
`max_bytes`. Sizes declared in the central directory can lie, so the bytes actually inflated
are counted too and extraction stops at the bound. Every message names the member as it is
in the archive, never a server folder.
"""
from __future__ import annotations

import lzma
import stat
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from core.errors import LimitExceeded, MalformedAsset, UnsafeReference
from pipeline.ingest import READERS

ROOT_SUFFIXES = tuple(READERS)
SCENE_SUFFIXES = tuple(s for s, kind in READERS.items() if kind != "mesh")  # glTF and USD
_CHUNK = 1 << 16


_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate",
            zipfile.ZIP_BZIP2: "bzip2", zipfile.ZIP_LZMA: "lzma"}


def extract(archive: Path, dest: Path, *, max_bytes: int, max_files: int, max_depth: int = 32,
            max_name: int = 255, max_ratio: float | None = None, label: str = "") -> list[str]:
    """Extract `archive` into the (new, empty) folder `dest`; returns the member paths written.
    `max_ratio` bounds the unpacked bytes per byte of the archive, so a small upload cannot
    take much disk even for the moment before it is refused."""
    name = label or archive.name
    if max_ratio:
        max_bytes = min(max_bytes, int(max_ratio * max(archive.stat().st_size, 1)))
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError, ValueError, NotImplementedError) as exc:
        raise MalformedAsset(name, f"not a readable zip archive ({_no_paths(exc)})") from None
    with zf:
        try:
            return _extract(zf, dest, name, max_bytes, max_files, max_depth, max_name)
        except OSError as exc:  # e.g. a name the file system refuses: the member is the problem
            raise MalformedAsset(name, f"cannot extract the archive ({exc.strerror or exc})") from None


def _extract(zf: zipfile.ZipFile, dest: Path, name: str, max_bytes: int, max_files: int,
             max_depth: int, max_name: int) -> list[str]:
    members = [m for m in zf.infolist() if not m.is_dir()]
    if len(members) > max_files:
        raise LimitExceeded(name, f"archive holds {len(members)} files, more than the limit "
                                  f"of {max_files}")
    declared = sum(m.file_size for m in members)
    if declared > max_bytes:
        raise LimitExceeded(name, f"archive unpacks to {declared} bytes, more than the limit "
                                  f"of {max_bytes} bytes for an archive of its size")
    targets = [(_safe_member(m, name, max_depth, max_name), m) for m in members]
    _check_layout(targets, name)
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
        except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError, RuntimeError,
                ValueError, zlib.error, lzma.LZMAError) as exc:  # RuntimeError: a password is needed
            raise MalformedAsset(name, f"cannot inflate {info.filename!r} ({exc})") from None
        written.append(rel.as_posix())
    return written


def _check_layout(targets: list[tuple[PurePosixPath, zipfile.ZipInfo]], name: str) -> None:
    """One name, one regular file: no duplicates, no file that is also a folder."""
    files: dict[str, str] = {}
    for rel, info in targets:
        key = rel.as_posix()
        if key in files:
            raise MalformedAsset(name, f"archive holds {info.filename!r} twice")
        files[key] = info.filename
    for rel, info in targets:
        for parent in rel.parents:
            if parent.as_posix() in files:
                raise MalformedAsset(name, f"archive uses {files[parent.as_posix()]!r} both as a file "
                                           f"and as the folder of {info.filename!r}")


def _safe_member(info: zipfile.ZipInfo, name: str, max_depth: int = 32, max_name: int = 255) -> PurePosixPath:
    raw = info.filename
    shown = raw if len(raw) <= 80 else raw[:60] + "..." + raw[-16:]
    if info.flag_bits & 0x1:
        raise MalformedAsset(name, f"archive entry {shown!r} is encrypted; upload it unencrypted")
    if info.compress_type not in _METHODS:
        raise MalformedAsset(name, f"archive entry {shown!r} uses compression method "
                                   f"{info.compress_type}; supported: " + ", ".join(_METHODS.values()))
    mode = info.external_attr >> 16
    if mode and (stat.S_ISLNK(mode) or not (stat.S_ISREG(mode) or stat.S_IFMT(mode) == 0)):
        raise UnsafeReference(name, f"archive entry {shown!r} is a link or special file; only "
                                    "regular files are accepted")
    text = raw.replace("\\", "/")
    if "\x00" in text:
        raise UnsafeReference(name, f"archive entry {shown!r} has a NUL byte in its name")
    path = PurePosixPath(text)
    if text.startswith("/") or path.is_absolute() or (len(text) > 1 and text[1] == ":"):
        raise UnsafeReference(name, f"archive entry {shown!r} is an absolute path")
    if any(part == ".." for part in path.parts):
        raise UnsafeReference(name, f"archive entry {shown!r} escapes the archive's folder")
    parts = [p for p in path.parts if p not in ("", ".")]
    if not parts:
        raise MalformedAsset(name, f"archive entry {shown!r} has no file name")
    if len(parts) > max_depth:
        raise LimitExceeded(name, f"archive entry {shown!r} is {len(parts)} levels deep, more than "
                                  f"the limit of {max_depth}")
    longest = max(parts, key=len)
    if len(longest) > max_name:
        raise LimitExceeded(name, f"archive entry {shown!r} has a name part of {len(longest)} "
                                  f"characters, more than the limit of {max_name}")
    return PurePosixPath(*parts)


class AmbiguousEntry(MalformedAsset):
    """Several files could be the archive's asset; `candidates` names them (the 422's body)."""

    def __init__(self, path, reason: str, candidates: tuple[str, ...] = ()):
        super().__init__(path, reason)
        self.candidates = tuple(candidates)

    def __reduce__(self):
        return (type(self), (self.path, self.reason, self.candidates))


def usd_layers(files: list[str]) -> list[str]:
    """The USD layers among `files`, which may reference one another (kit parts)."""
    return [f for f in files if f.lower().endswith((".usd", ".usda", ".usdc"))
            and "__MACOSX" not in f]


def find_root(files: list[str], name: str, main: str | None = None,
              parts: frozenset[str] | set[str] = frozenset()) -> str:
    """The asset file to ingest among extracted `files`: `main` when given, else, leaving
    out `parts` (USD files another one references: pipeline.library, the rule asset-bake
    follows), the only supported file at the shallowest depth, else the one whose stem
    matches the archive's; else AmbiguousEntry naming the candidates."""
    if main:
        wanted = PurePosixPath(main.replace("\\", "/")).as_posix().lstrip("./")
        if wanted not in files:
            raise MalformedAsset(name, f"main file {main!r} is not in the archive")
        return wanted
    candidates = [f for f in files if f.lower().endswith(ROOT_SUFFIXES) and "__MACOSX" not in f
                  and f not in parts]
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
    raise AmbiguousEntry(name, f"archive holds several entry points ({', '.join(top[:8])}); "
                               "upload again naming one in the `main` form field (the "
                               "response's `candidates` lists them)", tuple(top[:64]))


def _no_paths(exc: Exception) -> str:
    """zipfile's message without the server path it sometimes includes."""
    return str(exc).replace(str(getattr(exc, "filename", "") or "\0"), "the upload")


def drop_unreferenced(dest: Path, keep: list[str]) -> int:
    """Delete the extracted files the asset does not reference (`keep`: files read while
    ingesting); returns bytes freed. Empty folders go too."""
    wanted = {Path(p).resolve() for p in keep}
    freed = 0
    for path in sorted(dest.rglob("*"), reverse=True):
        if path.is_file() and path.resolve() not in wanted:
            freed += path.stat().st_size
            path.unlink()
        elif path.is_dir() and not any(path.iterdir()):
            path.rmdir()
    return freed
