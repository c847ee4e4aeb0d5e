"""Which files of a library (a folder, an uploaded zip) are its entry points.

A USD file that another USD file of the library references, sublayers or payloads is a part
of a kit, not an asset of its own: `asset-bake LIB/` skips it and an uploaded zip does not
take it as its entry point (service.archive.find_root), one rule for both.
"""
from __future__ import annotations

from pathlib import Path

USD_LAYER_SUFFIXES = (".usd", ".usda", ".usdc")


def usd_parts(files: list[Path]) -> dict[str, str]:
    """{file: a file that uses it} for the USD files among `files` that another one of them
    references, sublayers or payloads: parts of a kit, not its entry points. Read with Sdf
    alone (no composition); a file that does not open is left to fail in its own bake."""
    usd = {f.resolve(): str(f) for f in files if f.suffix.lower() in USD_LAYER_SUFFIXES}
    if len(usd) < 2:
        return {}
    from pxr import Sdf, Tf, UsdUtils  # heavy: only for a folder with several USD files

    parts: dict[str, str] = {}
    for real, text in usd.items():
        try:
            subs, refs, payloads = UsdUtils.ExtractExternalReferences(str(real))
        except Tf.ErrorException:
            continue
        layer = Sdf.Layer.FindOrOpen(str(real))
        for dep in [*subs, *refs, *payloads]:
            target = Path(layer.ComputeAbsolutePath(dep)).resolve() if layer else None
            if target in usd and target != real:
                parts.setdefault(usd[target], text)
    return parts


DRAWN_TYPES = frozenset({"Mesh", "Cube", "Sphere", "Cylinder", "Cone", "Capsule", "Plane",
                         "PointInstancer", "BasisCurves", "NurbsCurves", "Points", "NurbsPatch",
                         "TetMesh", "HermiteCurves"})


def drawless(files: list[Path]) -> set[str]:
    """The USD layers among `files` that can draw nothing: no gprim spec of their own and no
    sublayer, reference or payload that could bring one (a kit's material library). Sdf
    alone; a layer that does not open is not listed (its own read says why)."""
    from pxr import Sdf, Tf, UsdUtils

    out = set()
    for f in files:
        if f.suffix.lower() not in USD_LAYER_SUFFIXES:
            continue
        try:
            if any(UsdUtils.ExtractExternalReferences(str(f))):
                continue
            layer = Sdf.Layer.FindOrOpen(str(f))
        except Tf.ErrorException:
            continue
        if layer is None:
            continue
        if not _spec_types(layer) & DRAWN_TYPES:
            out.add(str(f))
    return out


def _spec_types(layer) -> set[str]:
    """The typeName of every prim spec in `layer`, variants' included."""
    from pxr import Sdf

    types: set[str] = set()

    def visit(path) -> None:
        if path.IsPrimPath() or path.IsPrimVariantSelectionPath():
            spec = layer.GetPrimAtPath(path)
            if spec:
                types.add(spec.typeName)
    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return types
