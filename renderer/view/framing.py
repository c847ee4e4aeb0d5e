"""The camera of a render request, for the raster renderer, the ray tracer and `auto` alike:
the asset's own camera when `options.camera` names one, else renderer.view.camera's framing fitted
on the asset's support points (backdrops left out, flat assets not seen edge-on); and whether
the frame gets a ground shadow (renderer.raster.shadow), which the framing then keeps in view."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from core.baked import BakedAsset
from core.errors import NotInAsset
from core.hull import support_points
from core.options import RenderOptions
from renderer.raster import shadow
from renderer.view.camera import Camera, frame_bounds, scene_camera


def frame_camera(bounds: np.ndarray, options: RenderOptions,
                 points: np.ndarray | None = None) -> tuple[Camera, bool, str]:
    """The camera of a frame of an object with these `bounds` (framed on its `points`, see
    renderer.view.camera), whether it gets a ground shadow, and why. With a shadow and no set
    distance the framing includes the shadow's core on the ground."""
    args = (options.width, options.height, options.yaw, options.pitch, options.fov)
    camera = frame_bounds(bounds, *args, options.distance, options.target, points=points)
    shadowed, why = shadow.decide(bounds, camera.position, options.shadow, options.background)
    if shadowed and options.distance is None and options.target is None:
        ground = shadow.framed_bounds(bounds)
        if points is not None:  # the object, and its outline pushed out on the ground
            points = np.concatenate([points, shadow.ground_outline(bounds, points)])
        camera = frame_bounds(ground, *args, points=points)
    return camera, shadowed, why


def request_camera(asset: BakedAsset, options: RenderOptions) -> Camera:
    """The camera a render of `asset` with `options` has. NotInAsset for an unknown camera."""
    return asset_camera(asset, options)[0]


def asset_camera(asset: BakedAsset, options: RenderOptions) -> tuple[Camera, bool, str]:
    """The camera of the request, whether the frame gets a ground shadow, and why."""
    extent = getattr(asset, "extent", None)
    if options.camera is not None:
        cam = _covering(scene_camera(_named_camera(asset, options.camera), asset.bounds,
                                     options.width, options.height), extent)
        return (cam, *shadow.decide(asset.bounds, cam.position, options.shadow, options.background))
    yaw, pitch = _not_edge_on(asset.bounds, options)
    if (yaw, pitch) != (options.yaw, options.pitch):
        options = dataclasses.replace(options, yaw=yaw, pitch=pitch)
    cam, shadowed, why = frame_camera(asset.bounds, options, framing_points(asset))
    return _covering(cam, extent), shadowed, why


def _named_camera(asset: BakedAsset, spec: str):
    cams = list(getattr(asset, "cameras", []))
    names = [c.name for c in cams]
    if spec.isdigit() and int(spec) < len(cams):
        return cams[int(spec)]
    if spec in names:
        return cams[names.index(spec)]
    if not names:
        raise NotInAsset(getattr(asset, "source", "asset"), f"no camera {spec!r}: the asset has "
                         "no cameras (leave camera out to frame it)")
    listed = ", ".join(f"{i} {n!r}" for i, n in enumerate(names))
    raise NotInAsset(getattr(asset, "source", "asset"),
                     f"no camera {spec!r}: the asset has {len(names)} camera"
                     f"{'s' if len(names) > 1 else ''} (index 0..{len(names) - 1} or name: {listed})")


_framing_points: dict[str, np.ndarray] = {}


def framing_points(asset: BakedAsset) -> np.ndarray | None:
    """World-space support points (core.hull) of every instance of every mesh."""
    pts = _framing_points.get(asset.key)
    if pts is None:
        parts = []
        for m in asset.meshes:
            if len(m.positions) == 0:
                continue
            local = support_points(m.positions) if m.support is None else m.support  # baked
            for t in np.asarray(m.transforms, np.float64):
                parts.append(local @ t[:3, :3].T + t[:3, 3])
        lo, hi = np.asarray(asset.bounds, np.float64)
        tol = 1e-6 * max(float(np.abs(hi - lo).max()), 1e-12)
        pts = np.concatenate(parts) if parts else np.zeros((0, 3))
        pts = pts[np.all((pts >= lo - tol) & (pts <= hi + tol), axis=1)]  # backdrops are outside
        if len(pts) == 0:
            return None
        pts = support_points(pts)
        if len(_framing_points) > 64:
            _framing_points.clear()
        _framing_points[asset.key] = pts
    return pts


FLAT = 0.12     # an extent under this share of the largest makes an asset flat (a card, a floor tile)
GRAZING = 30.0  # degrees: a default view closer than this to a flat asset's plane is raised (the
                # default pitch, 25, would see a floor tile too flat)


def _not_edge_on(bounds: np.ndarray, options) -> tuple[float, float]:
    """The default yaw/pitch, turned so a flat asset (a floor plane, a card) is not seen
    edge-on: the view is raised to 45 degrees off its plane. Angles a request sets are kept."""
    yaw, pitch = options.yaw, options.pitch
    defaults = RenderOptions()
    if (yaw, pitch) != (defaults.yaw, defaults.pitch) or options.distance is not None:
        return yaw, pitch
    size = np.ptp(np.asarray(bounds, np.float64), axis=0)
    axis = int(np.argmin(size))
    if size.max() <= 0 or size[axis] > FLAT * size.max():
        return yaw, pitch
    y, p = math.radians(yaw), math.radians(pitch)
    view = np.array([math.sin(y) * math.cos(p), math.sin(p), math.cos(y) * math.cos(p)])
    if math.degrees(math.asin(min(abs(view[axis]), 1.0))) >= GRAZING:
        return yaw, pitch
    if axis == 1:
        return yaw, 45.0
    return (45.0 if axis == 0 else yaw), pitch  # a card facing X: turn toward it


def _covering(cam: Camera, extent) -> Camera:
    """`cam` with its far plane pushed out to the backdrop geometry framing left out."""
    if extent is None:
        return cam
    lo, hi = np.asarray(extent, np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    far = float(np.linalg.norm(corners - cam.position, axis=1).max()) * 1.01
    return dataclasses.replace(cam, far=max(cam.far, far)) if far > cam.far else cam
