"""The camera of a frame: the framing of renderer.camera applied to a baked asset (fitted on
its support points), and whether the frame gets a ground shadow (renderer.shadow), which the
framing then keeps in view. The raster renderer, the ray tracer and `auto` all use it."""
from __future__ import annotations

import numpy as np

from core.baked import BakedAsset
from core.options import RenderOptions

from . import shadow
from .camera import Camera, frame_bounds, support_points


def frame_camera(bounds: np.ndarray, options: RenderOptions,
                 points: np.ndarray | None = None) -> tuple[Camera, bool, str]:
    """The camera of a frame of an object with these `bounds` (framed on its `points`, see
    renderer.camera), whether it gets a ground shadow, and why. With a shadow and no set
    distance the framing includes the shadow's core on the ground."""
    args = (options.width, options.height, options.yaw, options.pitch, options.fov)
    camera = frame_bounds(bounds, *args, options.distance, points=points)
    shadowed, why = shadow.decide(bounds, camera.position, options.shadow, options.background)
    if shadowed and options.distance is None:
        ground = shadow.framed_bounds(bounds)
        if points is not None:  # the object, and its outline pushed out on the ground
            points = np.concatenate([points, shadow.ground_outline(bounds, points)])
        camera = frame_bounds(ground, *args, points=points)
    return camera, shadowed, why


def asset_camera(asset: BakedAsset, options: RenderOptions) -> tuple[Camera, bool, str]:
    """frame_camera for a baked asset, framed on its support points (computed once per asset)."""
    return frame_camera(asset.bounds, options, framing_points(asset))


_framing_points: dict[str, np.ndarray] = {}


def framing_points(asset: BakedAsset) -> np.ndarray | None:
    """World-space support points of every instance of every mesh (renderer.camera)."""
    pts = _framing_points.get(asset.key)
    if pts is None:
        parts = []
        for m in asset.meshes:
            if len(m.positions) == 0:
                continue
            local = support_points(m.positions)
            for t in np.asarray(m.transforms, np.float64):
                parts.append(local @ t[:3, :3].T + t[:3, 3])
        if not parts:
            return None
        pts = support_points(np.concatenate(parts))
        if len(_framing_points) > 64:
            _framing_points.clear()
        _framing_points[asset.key] = pts
    return pts
