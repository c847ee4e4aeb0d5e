"""USD layer graph safety: every file a stage would read is checked before it is composed.

`LayerGraph.open(path)` walks sublayers, references and payloads (all variants, authored or
not) layer by layer with Sdf alone, without composing, and refuses any that is a URI, an
absolute path, or resolves outside the asset's folder (or, for `.usdz`, outside the package),
through `..` or a symlink. A `.usdz` is checked as a zip before anything in it is opened:
entry count, declared sizes and stored-only entries (USD cannot read compressed ones, so
reading a file from it never decompresses). The opened layers are held so that composing
the stage afterwards reuses them instead of reading again.
"""
from __future__ import annotations

import logging
import os
import posixpath
import zipfile
from pathlib import Path
from urllib.parse import unquote

from pxr import Ar, Sdf, Tf, UsdUtils

from core.errors import LimitExceeded, MalformedAsset, MissingFile, UnsafeReference
from pipeline import deadline
from pipeline.limits import Limits
from pipeline.paths import UNCONFINED, relative_path_text, resolve_reference, sandbox_root

log = logging.getLogger(__name__)



class LayerGraph:
    """The asset's layers, opened and checked. `files` lists every file on disk read, in order
    (layers and textures; for what a .usdz holds, the package file itself), for content hashing."""

    def __init__(self, path: Path, limits: Limits, root: Path | None = None):
        self.path = Path(path)
        self.root = sandbox_root(self.path, root)
        self.stage = None  # the composed stage, once composed (material readers look there)
        self.limits = limits
        self.layers: dict[str, Sdf.Layer] = {}   # identifier -> layer (held open)
        self.files: list[str] = []
        self.absent: list[str] = []  # files looked for (inside the root) and not found
        self.warnings: list[str] = []
        self.packages: dict[str, zipfile.ZipFile] = {}
        self.unreadable: set[str] = set()  # dependencies with no USD file format (e.g. .mtlx)
        self.missing: dict[str, str] = {}  # absent reference / payload -> why (pxr reports use)

    # -- opening ------------------------------------------------------------------------
    def open(self) -> Sdf.Layer:
        real = self.path.resolve()
        if real.suffix.lower() == ".usdz":
            self._check_package(real)
        root_layer = self._open_layer(str(real), self.path)
        pending = [root_layer]
        while pending:
            deadline.check()
            layer = pending.pop()
            for dep in self._dependencies(layer):
                sublayer = dep in layer.subLayerPaths
                try:
                    target = self.resolve(layer, dep)
                except MissingFile as exc:
                    if not sublayer:  # a reference or payload: pxr composes without it, and
                        # says so (naming the file and the prim) only where it is used, not in
                        # a variant left unselected
                        self.missing[layer.ComputeAbsolutePath(dep)] = exc.reason
                        continue
                    self.unreadable.add(layer.ComputeAbsolutePath(dep))
                    self.warnings.append(f"{self._name(layer)}: sublayer {dep!r} not found; "
                                         "the stage is composed without it")
                    continue
                ext = Path(_inner(target) or target).suffix.lstrip(".")
                if Sdf.FileFormat.FindByExtension(ext) is None:
                    self.unreadable.add(target)
                    if ext.lower() != "mtlx":  # .mtlx documents are read by usd_materials
                        self.warnings.append(f"{self._name(layer)}: cannot read {dep!r} (no USD "
                                             "file format for it); its contents are skipped")
                    continue
                if ext.lower() == "usdz" and not Ar.IsPackageRelativePath(target):
                    self._package(target)  # checked once, however many layers refer to it
                if target not in self.layers:
                    try:
                        pending.append(self._open_layer(target, self._name(layer)))
                    except MalformedAsset as exc:
                        self.unreadable.add(target)
                        if not sublayer:  # pxr will not open it either: composed without it
                            self.warnings.append(f"{self._name(layer)}: {dep!r} is unreadable "
                                                 f"({exc.reason}); the prims it brings are "
                                                 "not drawn")
                            continue
                        self.warnings.append(f"{self._name(layer)}: sublayer {dep!r} is "
                                             f"unreadable ({exc.reason}); the stage is composed "
                                             "without it")
        return root_layer

    def _dependencies(self, layer: Sdf.Layer) -> list[str]:
        """Composition arcs, plus value clips and every other asset path the layer holds
        (all are checked: a hostile path is refused wherever it is authored)."""
        deps = [d for d in layer.GetCompositionAssetDependencies() if d]  # "" = internal arc
        try:
            subs, refs, payloads = UsdUtils.ExtractExternalReferences(layer.identifier)
        except Tf.ErrorException as exc:
            raise MalformedAsset(self._name(layer), f"cannot list its references: {exc}") from None
        for other in refs:  # asset-valued attributes and clips: checked, not opened
            if other and other not in deps:
                try:
                    self.resolve(layer, other)
                except MissingFile:
                    pass  # only an error if it is used (textures are resolved again then)
        return deps

    def _open_layer(self, identifier: str, referrer) -> Sdf.Layer:
        if not Ar.IsPackageRelativePath(identifier):
            self._check_size(Path(identifier))
        try:
            layer = Sdf.Layer.FindOrOpen(identifier)
        except Tf.ErrorException as exc:
            raise MalformedAsset(identifier,
                                 f"not a readable USD layer: {_first_line(exc)}") from None
        if layer is None:
            raise MalformedAsset(identifier, f"not a readable USD layer (referenced by {referrer})")
        self.layers[layer.identifier] = layer
        outer = _outer(layer.identifier)
        if outer not in self.files:
            self.files.append(outer)
        log.debug("opened layer %s", layer.identifier)
        return layer

    # -- resolving ----------------------------------------------------------------------
    def resolve(self, layer: Sdf.Layer, uri: str) -> str:
        """The identifier `uri`, authored in `layer`, names; refused when unsafe, MissingFile
        when absent. On disk it is a path; inside a package `pkg.usdz[inner/path]`."""
        if "[" in uri or "]" in uri or ":SDF_FORMAT_ARGS:" in uri:
            raise UnsafeReference(self._name(layer), f"refusing reference {uri!r}: package or "
                                                     "format-argument syntax is not accepted")
        if "${" in uri or uri.startswith("`"):
            raise UnsafeReference(self._name(layer), f"refusing reference {uri!r}: expression "
                                                     "variables are not evaluated")
        ident = layer.identifier
        if Ar.IsPackageRelativePath(ident):
            return self._resolve_in_package(layer, uri)
        if _outer(ident).lower().endswith(".usdz"):  # the package's root layer
            return self._resolve_in_package(layer, uri)
        here = Path(layer.realPath)
        try:
            resolve_reference(here, uri, base_dir=here.parent, root=self.root)  # safe, present
        except MissingFile:
            self._absent(layer.ComputeAbsolutePath(uri))
            raise
        # The identifier Ar itself will use (anchored, not symlink-resolved), so that composing
        # finds these very layers already open.
        return layer.ComputeAbsolutePath(uri)

    def resolve_file(self, referrer: str, uri: str) -> str:
        """As `resolve`, for a reference found in a file that is not a layer (a .mtlx
        document): relative to that file, inside the same root or package."""
        if Ar.IsPackageRelativePath(referrer):
            outer, inner = _outer(referrer), _inner(referrer)
            assert inner is not None  # a package-relative path has an inner part
            path_text = relative_path_text(referrer, uri)
            norm = posixpath.normpath(posixpath.join(posixpath.dirname(inner), path_text))
            if norm.startswith("..") or norm.startswith("/"):
                raise UnsafeReference(referrer, f"refusing reference {uri!r}: it leaves the package")
            if norm not in self._package(outer).NameToInfo:
                raise MissingFile(referrer, f"referenced file {uri!r} not found in the package")
            return Ar.JoinPackageRelativePath([outer, norm])
        try:
            return str(resolve_reference(Path(referrer), uri, root=self.root))
        except MissingFile:
            self._absent(str(Path(referrer).parent / relative_path_text(
                referrer, uri, absolute_ok=self.root == UNCONFINED)))
            raise

    def resolve_each(self, layer: Sdf.Layer, uri: str, placeholder: str,
                     values) -> dict[int, str]:
        """`resolve` of `uri` with `placeholder` replaced by each of `values` (a UDIM
        texture's tile numbers), for those that exist. On disk the folder is listed once and
        only names in it are resolved, and the pattern itself is recorded absent: the cache
        key holds which tiles exist (pipeline.cache.tiles_present), not each absent tile."""
        here = None if Ar.IsPackageRelativePath(layer.identifier) or \
            _outer(layer.identifier).lower().endswith(".usdz") else Path(layer.realPath).parent
        return self._each(lambda text: self.resolve(layer, text), here, layer.ComputeAbsolutePath,
                          uri, placeholder, values)

    def resolve_file_each(self, referrer: str, uri: str, placeholder: str,
                          values) -> dict[int, str]:
        """`resolve_each` for a reference in a file that is not a layer (`resolve_file`)."""
        here = None if Ar.IsPackageRelativePath(referrer) else Path(referrer).parent
        return self._each(lambda text: self.resolve_file(referrer, text), here,
                          lambda text: str(Path(referrer).parent / text), uri, placeholder, values)

    def _each(self, resolve, here: Path | None, absolute, uri: str, placeholder: str,
              values) -> dict[int, str]:
        values = list(values)
        names = None
        folder, _, name = unquote(uri).replace("\\", "/").rpartition("/")
        if here is not None and values and placeholder not in folder:
            try:
                names = set(os.listdir(here / folder))
            except OSError:
                names = set()
        found = {}
        before = len(self.absent)
        for k, value in enumerate(values):
            text = uri.replace(placeholder, str(value))
            # the first is always resolved: it refuses a pattern that leaves the root
            if k and names is not None and name.replace(placeholder, str(value)) not in names:
                continue
            try:
                found[value] = resolve(text)
            except MissingFile:
                continue
        if here is not None:  # which tiles exist is one entry of the key (pipeline.cache)
            del self.absent[before:]
            self._absent(absolute(uri))
        return found

    def _absent(self, path: str) -> None:
        """A file looked for inside the root and not there: in the cache key too, so that
        it appearing later (a restored texture) bakes again."""
        if path not in self.absent:
            self.absent.append(path)

    def _resolve_in_package(self, layer: Sdf.Layer, uri: str) -> str:
        name = self._name(layer)
        # Schemes, NUL bytes and absolute paths are refused by the shared rules; `..` is
        # followed lexically from the referring layer's own folder inside the package.
        path_text = relative_path_text(name, uri)
        here = posixpath.dirname(_inner(layer.identifier) or "")
        if posixpath.normpath(posixpath.join(here, path_text)).split("/")[0] == "..":
            raise UnsafeReference(name, f"refusing reference {uri!r}: it leaves the package")
        target = layer.ComputeAbsolutePath(uri)
        outer, inner = _outer(target), _inner(target)
        if inner is None or Path(outer).resolve() != Path(_outer(layer.identifier)).resolve():
            raise UnsafeReference(name, f"refusing reference {uri!r}: it leaves the package")
        if Ar.IsPackageRelativePath(inner):
            raise UnsafeReference(name, f"refusing reference {uri!r}: nested packages are not read")
        norm = posixpath.normpath(inner)
        if norm.startswith("..") or norm.startswith("/"):
            raise UnsafeReference(name, f"refusing reference {uri!r}: it leaves the package")
        if norm not in self._package(outer).NameToInfo:
            raise MissingFile(name, f"referenced file {uri!r} not found in the package")
        return Ar.JoinPackageRelativePath([outer, norm])

    # -- reading files --------------------------------------------------------------------
    def read_bytes(self, identifier: str) -> bytes:
        """Bytes of a file resolved by `resolve` (on disk or stored in the package)."""
        if Ar.IsPackageRelativePath(identifier):
            outer, inner = _outer(identifier), _inner(identifier)
            assert inner is not None  # a package-relative path has an inner part
            data = self._package(outer).read(inner)
        else:
            self._check_size(Path(identifier))
            data = Path(identifier).read_bytes()
        if _outer(identifier) not in self.files:
            self.files.append(_outer(identifier))
        return data

    def _check_size(self, path: Path) -> None:
        size = path.stat().st_size
        if size > self.limits.max_file_bytes:
            raise LimitExceeded(path, f"file is {size} bytes, over the limit of "
                                      f"{self.limits.max_file_bytes}")

    def _package(self, outer: str) -> zipfile.ZipFile:
        key = str(Path(outer).resolve())
        if key not in self.packages:
            self._check_package(Path(key))
        return self.packages[key]

    def _check_package(self, path: Path) -> None:
        """Bounds a .usdz before USD reads it: entry count, sizes, stored entries only."""
        key = str(path.resolve())
        try:
            zf = zipfile.ZipFile(path)
        except (zipfile.BadZipFile, OSError, ValueError) as exc:
            raise MalformedAsset(path, f"not a valid usdz (zip) package: {exc}") from None
        infos = zf.infolist()
        if len(infos) > self.limits.max_archive_files:
            raise LimitExceeded(path, f"package holds {len(infos)} files, over the limit of "
                                      f"{self.limits.max_archive_files}")
        total = sum(i.file_size for i in infos)
        if total > self.limits.max_unpacked_bytes:
            raise LimitExceeded(path, f"package unpacks to {total} bytes, over the limit of "
                                      f"{self.limits.max_unpacked_bytes}")
        if not infos:
            raise MalformedAsset(path, "package is empty")
        size = path.stat().st_size
        for info in infos:
            if info.compress_type != zipfile.ZIP_STORED or info.file_size != info.compress_size:
                raise MalformedAsset(path, f"package entry {info.filename!r} is compressed; usdz "
                                           "entries must be stored uncompressed")
            if info.header_offset + info.file_size > size:
                raise MalformedAsset(path, f"package entry {info.filename!r} runs past the end "
                                           "of the file (truncated)")
        if Path(infos[0].filename).suffix.lower() not in (".usd", ".usda", ".usdc"):
            raise MalformedAsset(path, f"package's first file {infos[0].filename!r} is not a USD "
                                       "layer")
        self.packages[key] = zf

    def _name(self, layer: Sdf.Layer) -> str:
        return layer.identifier if Ar.IsPackageRelativePath(layer.identifier) else layer.realPath

    def close(self) -> None:
        for zf in self.packages.values():
            zf.close()
        self.packages.clear()


def _outer(identifier: str) -> str:
    return Ar.SplitPackageRelativePathOuter(identifier)[0] if Ar.IsPackageRelativePath(identifier) \
        else identifier


def _inner(identifier: str) -> str | None:
    return Ar.SplitPackageRelativePathOuter(identifier)[1] if Ar.IsPackageRelativePath(identifier) \
        else None


def _first_line(exc: Exception) -> str:
    """The parser's own message out of a Tf error ("Error in 'fn' at line N in file F : 'MSG'")."""
    text = str(exc).split(" : '")[-1]
    lines = [ln.strip(" '\t") for ln in text.splitlines() if ln.strip(" '\t")]
    return lines[0][:300] if lines else type(exc).__name__
