"""Where on the screen a frame's surfaces and its ground shadow can reach, so that the final
pass (renderer.raster.final) does each kind of work only there.

On a CPU rasteriser every branch of a shader costs on every pixel, so the final pass is drawn
as several programs, each over the pixels that need it: the MSAA resolve and tone mapping
inside the object's silhouette bound (`object_polygon`: the projected convex hull of every
vertex, core.hull, baked with the asset; grown by more than a pixel), the ground shadow inside
the projection of its map (`screen_rect`). Both are conservative: outside them the work would
have produced exactly what the cheaper program writes.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from core import hull
from core.baked import BakedAsset
from renderer.view.camera import Camera

Rect = tuple[int, int, int, int]  # x, y, width, height in pixels; y down from the image top

PAD = 1.5                   # pixels the silhouette bound grows by (a pixel is touched if any
                            # of its samples is covered: half a pixel, plus rounding room)
_hulls: OrderedDict = OrderedDict()  # asset key -> world points of the convex hull
MAX_HULLS = 64


def hull_points(asset: BakedAsset) -> np.ndarray | None:
    """World-space points whose convex hull holds every drawn surface (core.hull): as baked
    (BakedAsset.hull), else computed and kept per asset. None: no bound."""
    if asset.hull is not None:
        return asset.hull if len(asset.hull) else None
    if asset.key in _hulls:
        _hulls.move_to_end(asset.key)
        return _hulls[asset.key]
    pts = _hulls[asset.key] = hull.hull_points(asset.meshes)
    while len(_hulls) > MAX_HULLS:
        _hulls.popitem(last=False)
    return pts


def _project(camera: Camera, points: np.ndarray, w: int, h: int) -> np.ndarray | None:
    """Pixel positions (x right, y down from the top) of world points; None when one lies at
    or behind the camera's plane (its projection is no bound)."""
    hom = np.c_[np.asarray(points, np.float64), np.ones(len(points))] @ (
        camera.projection_matrix() @ camera.view_matrix()).T
    scale = max(float(np.abs(hom[:, 3]).max(initial=0.0)), 1e-300)
    if len(hom) == 0 or not np.all(hom[:, 3] > 1e-9 * scale):
        return None
    ndc = hom[:, :2] / hom[:, 3:4]
    if not np.all(np.isfinite(ndc)) or np.abs(ndc).max() > 1e6:
        return None
    return np.stack([(ndc[:, 0] * 0.5 + 0.5) * w, (0.5 - ndc[:, 1] * 0.5) * h], axis=1)


_DIRECTIONS = np.array([[np.cos(a), np.sin(a)] for a in np.arange(16) * np.pi / 8])


def object_polygon(camera: Camera, hull: np.ndarray | None, w: int, h: int) -> np.ndarray | None:
    """A convex polygon (K x 2 pixels) holding every pixel any surface of the object can
    touch: the frame cut by the 16 half-planes, at every 22.5 degrees, that bound the
    projected hull grown by the pixel square. None when the object may reach anywhere."""
    if hull is None:
        return None
    px = _project(camera, hull, w, h)
    if px is None:
        return None
    reach = (px @ _DIRECTIONS.T).max(axis=0) + PAD * np.abs(_DIRECTIONS).sum(axis=1)
    poly = [(-1.0, -1.0), (w + 1.0, -1.0), (w + 1.0, h + 1.0), (-1.0, h + 1.0)]
    for (nx, ny), c in zip(_DIRECTIONS.tolist(), reach.tolist()):
        poly = _clip(poly, nx, ny, c)
        if len(poly) < 3:
            return np.zeros((0, 2))
    return np.array(poly)


def object_rect(camera: Camera, hull: np.ndarray | None, w: int, h: int) -> Rect | None:
    """The rectangle of pixels any surface of the object can touch (the projected hull's
    bounds grown by PAD, as object_polygon's bounding rectangle), None when the object may
    reach anywhere; width or height 0 when it is out of view."""
    if hull is None:
        return None
    px = _project(camera, hull, w, h)
    if px is None:
        return None
    x0 = min(max(int(np.floor(px[:, 0].min() - PAD)), 0), w)
    y0 = min(max(int(np.floor(px[:, 1].min() - PAD)), 0), h)
    x1 = min(int(np.ceil(px[:, 0].max() + PAD)) + 1, w)
    y1 = min(int(np.ceil(px[:, 1].max() + PAD)) + 1, h)
    return (x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))


def _clip(poly: list, nx: float, ny: float, c: float) -> list:
    """Sutherland-Hodgman: the part of convex `poly` where nx * x + ny * y <= c."""
    out = []
    for i, (x0, y0) in enumerate(poly):
        x1, y1 = poly[(i + 1) % len(poly)]
        d0, d1 = nx * x0 + ny * y0 - c, nx * x1 + ny * y1 - c
        if d0 <= 0:
            out.append((x0, y0))
        if (d0 <= 0) != (d1 <= 0):
            t = d0 / (d0 - d1)
            out.append((x0 + t * (x1 - x0), y0 + t * (y1 - y0)))
    return out


def bounding_rect(polygon: np.ndarray, w: int, h: int) -> Rect:
    """The pixels holding a polygon (K x 2, y from the top), within the frame."""
    x0, y0 = (max(int(np.floor(v)), 0) for v in polygon.min(axis=0))
    x1 = min(int(np.ceil(polygon[:, 0].max())) + 1, w)
    y1 = min(int(np.ceil(polygon[:, 1].max())) + 1, h)
    return (x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))


def screen_rect(camera: Camera, points: np.ndarray, w: int, h: int, pad: int = 2) -> Rect:
    """Pixels (grown by `pad`) holding the projection of every point, hence of their convex
    hull; the whole frame when a point lies at or behind the camera's plane."""
    px = _project(camera, points, w, h)
    if px is None:
        return (0, 0, w, h)
    x0 = int(max(np.floor(px[:, 0].min()) - pad, 0))
    y0 = int(max(np.floor(px[:, 1].min()) - pad, 0))
    x1 = int(min(np.ceil(px[:, 0].max()) + pad, w))
    y1 = int(min(np.ceil(px[:, 1].max()) + pad, h))
    return (x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))


def intersect(a: Rect, b: Rect) -> Rect | None:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    return (x0, y0, x1 - x0, y1 - y0) if x1 > x0 and y1 > y0 else None


def subtract(a: Rect, b: Rect) -> list[Rect]:
    """`a` less `b`, as up to four rectangles (bands above and below, then left and right)."""
    cut = intersect(a, b)
    if cut is None:
        return [a]
    ax1, ay1, cx1, cy1 = a[0] + a[2], a[1] + a[3], cut[0] + cut[2], cut[1] + cut[3]
    parts = [(a[0], a[1], a[2], cut[1] - a[1]), (a[0], cy1, a[2], ay1 - cy1),
             (a[0], cut[1], cut[0] - a[0], cut[3]), (cx1, cut[1], ax1 - cx1, cut[3])]
    return [r for r in parts if r[2] > 0 and r[3] > 0]
