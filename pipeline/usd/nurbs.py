"""UsdGeom NurbsPatch as Hydra Storm (usdview) draws it: a mesh over its control hull.

Storm 0.25 evaluates no NURBS. Its NURBS-approximating scene index turns a patch into a mesh
of (uVertexCount - 1) x (vVertexCount - 1) quads over the control points (row v, column u,
u fastest), keeping `orientation` and `doubleSided`, with subdivision scheme catmullClark
left to the mesh path: at usdview's default complexity that is the hull with smooth normals
(refined only at higher complexities). Order, knots, ranges, weights, uForm / vForm (no
wrap-around face) and trim curves are ignored: a trimmed patch is drawn whole. Measured
(bench/nurbs_stages.py): a cubic, a bilinear and a trimmed patch over one hull give the same
Storm frame, bit for bit.

`PatchHull` stands in for the UsdGeom.Mesh that StageReader triangulates: the hull's
topology with the patch's own points, normals and orientation. Its subdivision scheme is
catmullClark but not authored, as a mesh that leaves USD's fallback: smooth normals, no
refinement, Storm's default look. (NurbsCurves and HermiteCurves are Storm's linear curves
through their points: pipeline.usd.curves, through StageReader._swept.)
"""
from __future__ import annotations

import numpy as np
from pxr import UsdGeom, Vt


class _Unauthored:
    """An attribute's stand-in: a value that reads as never authored."""

    def __init__(self, value):
        self._value = value

    def Get(self, time=None):  # the Usd.Attribute spelling
        return self._value

    def HasAuthoredValue(self) -> bool:
        return False


def hull_faces(nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """(faceVertexCounts, faceVertexIndices) of the nu x nv hull's quads, Storm's order."""
    row, col = np.meshgrid(np.arange(nv - 1), np.arange(nu - 1), indexing="ij")
    first = (row * nu + col).reshape(-1)
    quads = np.stack([first, first + 1, first + nu + 1, first + nu], axis=1)
    return np.full(len(first), 4, np.int64), quads.reshape(-1).astype(np.int64)


class PatchHull:
    """The mesh Storm draws for a NurbsPatch, with UsdGeom.Mesh's getters (those that
    StageReader._triangulate reads)."""

    def __init__(self, patch: UsdGeom.NurbsPatch, nu: int, nv: int):
        self._patch = patch
        counts, indices = hull_faces(nu, nv)  # as Vt arrays, which read like the attributes'
        self._counts = Vt.IntArray.FromNumpy(counts.astype(np.int32))
        self._indices = Vt.IntArray.FromNumpy(indices.astype(np.int32))

    def GetFaceVertexCountsAttr(self):
        return _Unauthored(self._counts)

    def GetFaceVertexIndicesAttr(self):
        return _Unauthored(self._indices)

    def GetHoleIndicesAttr(self):
        return _Unauthored(None)

    def GetSubdivisionSchemeAttr(self):
        return _Unauthored(UsdGeom.Tokens.catmullClark)

    def GetPointsAttr(self):
        return self._patch.GetPointsAttr()

    def GetOrientationAttr(self):
        return self._patch.GetOrientationAttr()

    def GetNormalsAttr(self):
        return self._patch.GetNormalsAttr()

    def GetNormalsInterpolation(self):
        return self._patch.GetNormalsInterpolation()
