"""Content-addressed, atomic on-disk cache of baked assets and environments.

Layout under the cache root (default `$ASSET_PREVIEW_CACHE`, else `./.cache`):

    assets/<key>/        manifest.json + *.npz     one baked asset
    environments/<key>/  manifest.json + *.npz     one baked environment
    thumbnails/<key>/    manifest.json + an image  one rendered thumbnail (cli/thumbnails.py)
    sources/<id>.json    source index (below)
    tmp/                 entries being built, and entries being deleted

Key. SHA-256 over a canonical JSON of: the kind's format (BAKE_FORMAT_VERSION, or
ENVIRONMENT_FORMAT_VERSION for environments), the kind, the main file's suffix
and SHA-256, the (relative path, SHA-256) of every other file the asset read (Scene.files:
buffers, textures, USD layers), and the bake options. Same bytes and options -> same key,
wherever the files live; any changed byte -> a new key. The main file's name is not part of it.

Source index. Which files an asset reads is only known after ingest, yet a hit must be decided
without ingesting. So each bake records, under sources/<id> with id = hash(kind, main file
SHA-256, suffix, options, version), the dependency list it found with each file's SHA-256, and
the key. A lookup hashes the main file, reads that record and re-hashes the listed files: if all
match, the key follows (the same main bytes and the same dependency bytes make a deterministic
ingest read the same files). Several records per id are kept, newest first, for copies of one
main file beside different dependencies. A file the asset looked for and did not find (a USD
texture or reference missing at bake time: Scene.absent) is listed with no SHA-256, so its
appearing later is a change too. A UDIM texture's tiles (`name.<UDIM>.png`) are one such
entry, the pattern itself, whose hash is which tiles exist (`_dependency_hash`: one folder
listing), not 100 absent files each looked for again on every lookup; the tiles found are
hashed as files besides. Known gap: glTF does not report its absent files yet.

Atomicity. An entry is built in tmp/ on the same filesystem, then renamed into place; the
loser of a race (its rename finds the entry there) discards its copy. Entries are removed by
renaming them into tmp/ first, so readers see a whole entry or none. Every file in an entry
carries a size and SHA-256 in the manifest: eager files are checked on every load, large lazy
ones (textures) for size on load and fully on first read. A missing or mismatched file is
logged, the entry removed, and the caller rebakes. That check is also why nothing is fsynced:
an entry torn by a power cut fails it and is rebaked, so durability costs no bake time.
Loads touch the manifest's mtime, the recency that the optional size cap's least-recently-used
eviction goes by; tmp/ leftovers of crashed processes are swept after an hour.

Shared filesystems (one cache for many machines). What the root's filesystem must give:
rename(2) of a directory within it atomic, failing when the target is a non-empty directory
(local filesystems, NFSv3/v4, CephFS, Lustre, GPFS; the whole root on one filesystem, no
sub-folder mounted apart); close-to-open consistency, so a file closed on one host reads whole
on a host that opens it later (NFS's default: never mount with `nocto`); attribute caching
only delays seeing a new entry (a miss, a rebake, a lost rename race); host clocks within
minutes of each other (the tmp/ sweep compares file times with the local clock). FUSE mounts
of object stores (s3fs, gcsfuse, mountpoint-s3) lack atomic directory rename: not a cache root.
Object storage goes through fsspec beside this cache, not under it: see the README.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import re
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zstandard

from core.errors import AssetError
from pipeline.limits import pipeline_settings

log = logging.getLogger(__name__)

# 2: glTF skins, morphs, instancing, variants, cameras baked; 3: Material lobes;
# 4: textures as capped, zstd-compressed mip chains (were full-size .npy); 5: meshes' welded
# edges for edge anti-aliasing (core.adjacency), support and hull points (core.hull);
# 6: Material.thin_walled; 7: Light.shadow / shadow_color (UsdLux ShadowAPI);
# 8: Material.show_back_faces (USD single-sided gprims); 9: per-vertex ambient occlusion
# (pipeline.occlusion); 10: subdivision refines each primvar by its own interpolation;
# 11: UsdUVTexture sourceColorSpace honoured (auto by Hio's rule), textures re-encoded
# 12: ambient occlusion as uint8, emitters not occluding
# 13: the studio environment's bake comes from pipeline/data/studio_bakes.npz (float16 mips)
# 14: MaterialX images honour their declared colorspace (lin_rec709 colour images re-encoded)
# 15: Material.opacity_premultiplied (UsdPreviewSurface blended as Storm does)
# 16: MaterialX colour management: standard colour spaces (gamuts, transfers) to lin_rec709 for
#     colour constants and images
# 17: UDIM textures baked as one atlas, their meshes' UVs remapped into it (pipeline.udim)
# 18: ambient occlusion per placement of an instanced mesh (a row each) where the budget allows
# 19: Material.opacity_premultiplied also for MaterialX ND_UsdPreviewSurface; UsdPreviewSurface
#     opacityMode "presence" fades the whole colour
# 20: a glTF primitive without a material takes the spec's default material (white metal, rough)
# 21: USD BasisCurves (tubes) and Points (spheres) are read, no longer skipped
# 22: Light.shape / size (USD lights' extent: soft shadows in the ray tracer); CylinderLight read
# 23: USD NurbsPatch (its control hull), NurbsCurves and HermiteCurves (linear curves) are read
# 24: small meshes placed once with one material stored as one batch in world space (pipeline.batching)
# 25: Material.face_viewer (USD Points drawn as discs facing the viewer, as Storm's sprites)
# 26: per-vertex bent normals beside the ambient occlusion (pipeline.occlusion; the raster's image light)
# 27: emissive polygons as the raster's area lights (core.area_lights, area_lights.npz)
# 28: triangles split where the baked visibility varies across them (pipeline.occlusion)
BAKE_FORMAT_VERSION = 28
# Environment entries have their own format: a prefiltered light does not change with the mesh
# bake's format, and the filter's constants already key it (pipeline.environment.shipped), so a
# mesh-format bump neither rebakes every environment nor stales the shipped studio bake.
# 1: the layout of BAKE_FORMAT_VERSION 15 (irradiance SH, GGX mips, BRDF LUT)
# 2: the irradiance cube (core.irradiance) the raster's diffuse reads instead of the SH
ENVIRONMENT_FORMAT_VERSION = 2
# texture chains, compressed at every cold bake: zstd's default level. Against 9 on six chains
# (16.8 MB of texels) it compresses 3.7x faster for 1.19x the bytes, and old entries read the
# same (bench/RESULTS.md, "USD cold first image: imports, forks and compression")
ZSTD_LEVEL = 3
KINDS = ("assets", "environments", "thumbnails")
IMAGE_SUFFIXES = (".png", ".jpg", ".webp", ".gif")  # stored as they are (thumbnails' encoded files)
MANIFEST = "manifest.json"
_KEY = re.compile(r"[0-9a-f]{64}")
_RECORDS_PER_SOURCE = 8
_STALE_TMP_SECONDS = 3600


def format_version(kind: str) -> int:
    """The format an entry of this kind is keyed and stored under."""
    return ENVIRONMENT_FORMAT_VERSION if kind == "environments" else BAKE_FORMAT_VERSION


class NotInCache(AssetError):
    """No valid entry for a key (never baked, evicted, or found corrupt)."""


class CorruptEntry(NotInCache):
    """A lazily read file of an entry failed its checksum (the entry is removed; rebake it)."""


def default_cache_dir() -> Path:
    return Path(pipeline_settings().cache)


def parse_size(text: str | int | None) -> int | None:
    """'500M', '2G', '1048576' -> bytes; None or '' or 0 -> no cap."""
    if text in (None, "", 0, "0"):
        return None
    if isinstance(text, int):
        return text
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmgt]?)i?b?\s*", str(text).lower())
    if not m:
        raise ValueError(f"not a size: {text!r} (use e.g. 500M or 2G)")
    return int(float(m.group(1)) * 1024 ** " kmgt".index(m.group(2) or " "))


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


UDIM, UDIM_TILES = "<UDIM>", range(1001, 1101)  # as pipeline.usd.materials looks for them


def tiles_present(pattern: str | os.PathLike) -> list[int]:
    """The tile numbers whose file `pattern` (a path holding <UDIM>) names exists: one
    listing of its folder, or a look per tile when a folder's name holds the placeholder."""
    pattern = str(pattern)
    folder, name = os.path.split(pattern)
    if UDIM in folder:
        return [n for n in UDIM_TILES if os.path.isfile(pattern.replace(UDIM, str(n)))]
    try:
        names = set(os.listdir(folder or "."))
    except OSError:
        return []
    return [n for n in UDIM_TILES if name.replace(UDIM, str(n)) in names]


def _dependency_hash(path: Path) -> str | None:
    """A dependency's hash as recorded: a file's SHA-256, None when it is absent; for a UDIM
    pattern, a digest of which tiles exist (None when none does)."""
    if UDIM in path.name or UDIM in str(path.parent):
        present = tiles_present(path)
        return _digest(["udim", present]) if present else None
    try:
        return file_sha256(path)
    except OSError:
        return None


def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@dataclass
class SourceFiles:
    """An asset's main file and the files it depends on, hashed."""
    main: Path
    main_sha256: str
    deps: list[tuple[str, str | None]] = field(default_factory=list)  # (path relative to main's folder, sha256; None: absent)

    @classmethod
    def hash(cls, main: str | os.PathLike, files=(), absent=()) -> "SourceFiles":
        """`absent`: files the asset looked for and did not find; recorded as such, so that
        one appearing later, or a copy of the main file beside them, is another key."""
        main = Path(main).resolve()
        deps: dict[str, str | None] = {}
        for f in absent:
            f = Path(f).resolve()
            if UDIM in str(f) or not f.exists():
                deps[Path(os.path.relpath(f, main.parent)).as_posix()] = _dependency_hash(f)
        for f in files:
            f = Path(f).resolve()
            if f == main:
                continue
            # relative even above the main file's folder (../textures): a moved tree keeps its key
            deps[Path(os.path.relpath(f, main.parent)).as_posix()] = file_sha256(f)
        return cls(main, file_sha256(main), sorted(deps.items(), key=lambda d: d[0]))

    def key(self, kind: str, options: dict) -> str:
        return _digest({"format": format_version(kind), "kind": kind, "suffix": self.main.suffix.lower(),
                        "main": self.main_sha256, "deps": self.deps, "options": options})

    def inputs(self) -> list[dict]:
        """For manifests: every input file with its checksum."""
        return [{"path": str(self.main), "sha256": self.main_sha256}] + [
            {"path": rel, "sha256": sha} for rel, sha in self.deps]


@dataclass
class Entry:
    kind: str
    key: str
    path: Path
    manifest: dict
    arrays: dict[str, dict[str, np.ndarray] | np.ndarray]  # file name -> its array(s), eager ones
    cache: "Cache | None" = None

    def read(self, name: str):
        """A file's array(s): eager ones from memory, lazy ones read and checksummed now."""
        if name in self.arrays:
            return self.arrays[name]
        try:
            return _verified(self.path, name, self.manifest["files"][name])
        except _Invalid as exc:
            self.invalid(name, str(exc))

    def invalid(self, name: str, why: str):
        """A file of this entry that checksummed but does not hold what the manifest says:
        remove the entry and raise CorruptEntry."""
        if self.cache is not None:
            self.cache._corrupt(self.kind, self.key, why if why.startswith(name) else f"{name}: {why}")
        raise CorruptEntry(self.path, f"{why}; entry removed, bake the asset again")


class Cache:
    """One cache root. Safe to share between processes and machines on one filesystem."""

    def __init__(self, root: str | os.PathLike | None = None, max_bytes: int | str | None = None):
        self.root = Path(root) if root is not None else default_cache_dir()
        if max_bytes is None:
            max_bytes = pipeline_settings().cache_max_bytes
        self.max_bytes = parse_size(max_bytes)

    def entry_dir(self, kind: str, key: str) -> Path:
        if kind not in KINDS:
            raise ValueError(f"unknown cache kind {kind!r}")
        if not _KEY.fullmatch(key or ""):
            raise NotInCache(key, "not a cache key (64 lowercase hex digits)")
        return self.root / kind / key

    # -- entries -------------------------------------------------------------------------------

    def load(self, kind: str, key: str, lazy=None) -> Entry | None:
        """The verified entry, or None (absent, or corrupt: then logged and removed).

        Files for which `lazy(name)` is true (large textures a caller may never need) are only
        checked for presence and size here, and fully checksummed by `Entry.read` on first use."""
        path = self.entry_dir(kind, key)
        try:
            manifest = json.loads((path / MANIFEST).read_bytes())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            return self._corrupt(kind, key, f"unreadable manifest ({exc})")
        if manifest.get("format") != format_version(kind) or manifest.get("key") != key:
            return self._corrupt(kind, key, "manifest of another format or key")
        arrays = {}
        for name, meta in manifest.get("files", {}).items():
            if lazy is not None and lazy(name):
                try:
                    size = (path / name).stat().st_size
                except OSError as exc:
                    return self._corrupt(kind, key, f"{name}: {exc.strerror or exc}")
                if size != meta.get("bytes"):
                    return self._corrupt(kind, key, f"{name}: {size} bytes, manifest says {meta.get('bytes')}")
                continue
            try:
                arrays[name] = _verified(path, name, meta)
            except _Invalid as exc:
                return self._corrupt(kind, key, str(exc))
        try:
            os.utime(path / MANIFEST)  # recency for LRU eviction
        except OSError:
            pass  # read-only cache: eviction order degrades, loading does not
        return Entry(kind, key, path, manifest, arrays, self)

    def store(self, kind: str, key: str, manifest: dict, arrays: dict, replace: bool = False) -> Entry:
        """Write an entry atomically; if another process got there first, keep theirs (or, with
        `replace`, as after a forced rebake, swap ours in).

        `arrays` maps file names to what they hold: `x.npz` a dict of arrays, `x.npy` one array
        (loaded without a copy), `x.zst` a list of arrays whose bytes are concatenated and
        zstd-compressed as one frame (texture mip chains; read back still compressed, after
        the checksum: the reader knows the shapes and decompresses the prefix it needs). The checksum covers the bytes on disk, compressed ones included."""
        final = self.entry_dir(kind, key)
        tmp = self._tmp_dir(f"{kind[:3]}-{key[:16]}")
        try:
            manifest = dict(manifest, format=format_version(kind), key=key, files={})
            for name, value in arrays.items():
                data = _encode(name, value)
                _write(tmp / name, data)
                manifest["files"][name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
            _write(tmp / MANIFEST, json.dumps(manifest, indent=1, default=_json_default).encode())
            final.parent.mkdir(parents=True, exist_ok=True)
            for attempt in range(2):
                try:
                    os.rename(tmp, final)
                    log.info("cache: stored %s/%s", kind, key)
                    break
                except OSError:
                    if not (final / MANIFEST).exists():
                        if attempt == 0 and final.exists():
                            self.remove(kind, key)  # a manifest-less leftover: not an entry
                            continue
                        raise  # not a race: the cache cannot be written
                    if attempt == 0 and (replace or self.load(kind, key) is None):
                        if replace:
                            self.remove(kind, key)
                        continue  # what was there is gone now (replaced, or was corrupt)
                    log.info("cache: %s/%s was stored concurrently; discarding our copy", kind, key)
                    break
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        self.evict(keep={(kind, key)})
        return Entry(kind, key, final, manifest, arrays, self)

    def touch(self, kind: str, key: str) -> None:
        """Mark an entry as just used, so eviction (least recently used first) keeps it."""
        try:
            os.utime(self.entry_dir(kind, key) / MANIFEST)
        except (OSError, NotInCache):
            pass  # gone, read-only or not a key: the next load finds out

    def remove(self, kind: str, key: str) -> None:
        """Delete an entry: renamed away first so no reader ever sees half of it."""
        path = self.entry_dir(kind, key)
        trash = self._tmp_dir("trash", create=False)
        try:
            os.rename(path, trash)
        except OSError:
            return  # already gone (another process removed it)
        shutil.rmtree(trash, ignore_errors=True)

    def _corrupt(self, kind: str, key: str, why: str) -> Entry | None:  # None: load() returns it
        log.warning("cache: %s/%s is corrupt (%s); removing it to rebake", kind, key, why)
        self.remove(kind, key)
        return None

    def _tmp_dir(self, prefix: str, create: bool = True) -> Path:
        path = self.root / "tmp" / f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        path.parent.mkdir(parents=True, exist_ok=True)
        if create:
            path.mkdir()
        return path

    # -- source index --------------------------------------------------------------------------

    def _source_file(self, kind: str, main_sha256: str, suffix: str, options: dict) -> Path:
        ident = _digest({"format": format_version(kind), "kind": kind, "main": main_sha256,
                         "suffix": suffix.lower(), "options": options})
        return self.root / "sources" / f"{ident}.json"

    def lookup_source(self, kind: str, main: str | os.PathLike, options: dict) -> str | None:
        """Key of a previous bake of `main` with these options if no input changed since; else None."""
        main = Path(main).resolve()
        try:
            records = json.loads(self._source_file(kind, file_sha256(main), main.suffix, options).read_bytes())
        except (OSError, ValueError):
            return None
        hashes: dict[str, str | None] = {}
        for record in records if isinstance(records, list) else []:
            try:
                deps, key = record["deps"], record["key"]
                for rel, sha in deps:
                    if rel not in hashes:
                        hashes[rel] = _dependency_hash(main.parent / rel)
                    if hashes[rel] != sha:
                        break
                else:
                    return key
            except (KeyError, TypeError, ValueError):
                continue
        return None

    def record_source(self, kind: str, source: SourceFiles, options: dict, key: str) -> None:
        path = self._source_file(kind, source.main_sha256, source.main.suffix, options)
        record = {"key": key, "deps": [list(d) for d in source.deps]}
        try:
            old = json.loads(path.read_bytes())
            old = [r for r in old if isinstance(r, dict) and r.get("deps") != record["deps"]]
        except (OSError, ValueError, TypeError):
            old = []
        path.parent.mkdir(parents=True, exist_ok=True)
        # Written whole in tmp/ (same filesystem; swept there if we die) and renamed over:
        # readers on any machine see the old list or the new one, never half of one.
        tmp = self._tmp_dir("src", create=False)
        _write(tmp, json.dumps([record] + old[:_RECORDS_PER_SOURCE - 1]).encode())
        os.replace(tmp, path)  # last writer wins; a lost record only costs one rebake

    # -- size cap ------------------------------------------------------------------------------

    def entries(self) -> list[tuple[float, int, str, str]]:
        """(last use, bytes, kind, key) of every entry."""
        out = []
        for kind in KINDS:
            folder = self.root / kind
            if not folder.is_dir():
                continue
            for path in folder.iterdir():
                try:
                    used = (path / MANIFEST).stat().st_mtime
                    size = sum(f.stat().st_size for f in path.iterdir())
                except OSError:
                    continue  # being written or removed right now
                out.append((used, size, kind, path.name))
        return out

    def evict(self, keep=()) -> int:
        """Drop least recently used entries until under the cap; returns bytes freed."""
        self._sweep_tmp()
        if not self.max_bytes:
            return 0
        entries = sorted(self.entries())
        total = sum(e[1] for e in entries)
        freed = 0
        for used, size, kind, key in entries:
            if total - freed <= self.max_bytes:
                break
            if (kind, key) in keep:
                continue
            self.remove(kind, key)
            freed += size
            log.info("cache: evicted %s/%s (%d bytes, last used %s)", kind, key, size, time.ctime(used))
        return freed

    def _sweep_tmp(self) -> None:
        """Remove what crashed processes left in tmp/ (old enough that nobody is writing it)."""
        folder = self.root / "tmp"
        if not folder.is_dir():
            return
        cutoff = time.time() - _STALE_TMP_SECONDS
        for path in folder.iterdir():
            try:
                if path.stat().st_mtime < cutoff:
                    shutil.rmtree(path, ignore_errors=True)
            except OSError:
                pass


class _Invalid(Exception):
    """A cache file that is missing, unreadable, fails its checksum or does not decode."""


def _verified(folder: Path, name: str, meta: dict):
    """The array(s) of an entry's file, checked against its manifest record (size, SHA-256)."""
    try:
        data = _read(folder / name)
    except OSError as exc:
        raise _Invalid(f"{name}: {exc.strerror or exc}") from None
    if len(data) != meta.get("bytes") or hashlib.sha256(data).hexdigest() != meta.get("sha256"):
        raise _Invalid(f"{name}: checksum mismatch")
    try:
        return _decode(name, data)
    except Exception as exc:  # a checksummed file that numpy rejects: still corrupt
        raise _Invalid(f"{name}: {exc}") from None


def _encode(name: str, value) -> bytes:
    buf = io.BytesIO()
    if name.endswith(".npy"):
        np.save(buf, np.ascontiguousarray(value), allow_pickle=False)
    elif name.endswith(".npz"):
        np.savez(buf, **value)
    elif name.endswith(".zst"):
        raw = b"".join(np.ascontiguousarray(a).tobytes() for a in value)
        return zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(raw)
    elif name.endswith(IMAGE_SUFFIXES):
        return bytes(value)
    else:
        raise ValueError(f"cache files are .npy, .npz, .zst or encoded images, not {name!r}")
    return buf.getvalue()


def _decode(name: str, data: bytearray):
    if name.endswith(IMAGE_SUFFIXES):
        return data
    if name.endswith(".zst"):
        return data  # still compressed: the reader decompresses what it needs (bake._read_chain)
    if name.endswith(".npz"):
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    # .npy: parse the header, then view the bytes already read (no second copy).
    buf = io.BytesIO(memoryview(data)[:4096])
    fmt = np.lib.format
    read_header = fmt.read_array_header_1_0 if fmt.read_magic(buf) == (1, 0) else fmt.read_array_header_2_0
    shape, fortran, dtype = read_header(buf)
    if dtype.hasobject or fortran:
        raise ValueError("unexpected array layout")
    count = int(np.prod(shape, dtype=np.int64))
    return np.frombuffer(data, dtype, count, offset=buf.tell()).reshape(shape)


def _read(path: Path) -> bytearray:
    """Whole file into a writable buffer (arrays viewing it stay writable)."""
    with open(path, "rb", buffering=0) as f:
        size = os.fstat(f.fileno()).st_size
        data = bytearray(size)
        view = memoryview(data)
        got = 0
        while got < size and (n := f.readinto(view[got:])):
            got += n
    return data if got == size else data[:got]


def _write(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
