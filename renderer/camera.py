"""The camera convention, shared by the raster renderer, the ray tracer and the reference.

The camera looks at the centre of the world bounds. yaw 0, pitch 0 puts it on the +Z side
looking toward -Z with +Y up; positive yaw turns it toward +X about +Y; positive pitch raises
it toward +Y. fov is vertical, in degrees; distance is in scene units from the bounds centre.
Without a distance, the camera is placed so the bounding sphere fills the frame with a margin
at any aspect ratio.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MARGIN = 1.08  # bounding-sphere radius is scaled by this when auto-framing


@dataclass(frozen=True)
class Camera:
    position: np.ndarray  # world
    target: np.ndarray
    up: np.ndarray
    fov: float            # vertical, degrees
    width: int
    height: int
    near: float
    far: float

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors in world space."""
        f = self.target - self.position
        f = f / np.linalg.norm(f)
        r = np.cross(f, self.up)
        r = r / np.linalg.norm(r)
        return r, np.cross(r, f), f

    def view_matrix(self) -> np.ndarray:
        r, u, f = self.basis()
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ self.position
        return m

    def projection_matrix(self) -> np.ndarray:
        """OpenGL perspective projection (depth -1..1 in NDC)."""
        t = 1.0 / math.tan(math.radians(self.fov) / 2)
        n, f = self.near, self.far
        m = np.zeros((4, 4))
        m[0, 0] = t / self.aspect
        m[1, 1] = t
        m[2, 2] = (f + n) / (n - f)
        m[2, 3] = 2 * f * n / (n - f)
        m[3, 2] = -1.0
        return m

    def ray_directions(self) -> np.ndarray:
        """Unit world directions through pixel centres, H x W x 3, row 0 at the image top."""
        r, u, f = self.basis()
        th = math.tan(math.radians(self.fov) / 2)
        x = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * th * self.aspect
        y = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * th
        d = f + x[None, :, None] * r + y[:, None, None] * u
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def frame_bounds(bounds: np.ndarray, width: int, height: int, yaw: float = 0.0,
                 pitch: float = 0.0, fov: float = 40.0, distance: float | None = None) -> Camera:
    """Camera for world `bounds` (2 x 3) following the convention above."""
    lo, hi = np.asarray(bounds, np.float64)
    center = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    half_v = math.radians(fov) / 2
    half_h = math.atan(math.tan(half_v) * width / height)
    if distance is None:
        distance = radius * MARGIN / math.sin(min(half_v, half_h))
    distance = max(float(distance), 1e-6)
    yaw_r = math.radians(yaw)
    pitch_r = math.radians(max(-89.9, min(89.9, pitch)))  # avoid a degenerate up vector
    offset = np.array([math.sin(yaw_r) * math.cos(pitch_r), math.sin(pitch_r),
                       math.cos(yaw_r) * math.cos(pitch_r)])
    near = max(distance - radius * 1.05, radius * 1e-3, distance * 1e-4)
    # Far from a small object, distance +- radius rounds to one value: keep far beyond near.
    far = max(distance + radius * 1.05, near * (1 + 1e-6))
    return Camera(position=center + distance * offset, target=center, up=np.array([0.0, 1.0, 0.0]),
                  fov=fov, width=width, height=height, near=near, far=far)
