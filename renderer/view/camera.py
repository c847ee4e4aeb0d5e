"""The camera convention, shared by the raster renderer, the ray tracer and the reference.

The camera looks at `target` (default: the centre of the world bounds). yaw 0, pitch 0 puts it on the +Z side
looking toward -Z with +Y up; positive yaw turns it toward +X about +Y; positive pitch raises
it toward +Y. fov is vertical, in degrees; distance is in scene units from the bounds centre.
Without a distance, the camera keeps that direction and is moved (back and sideways) until the
object's points (its support points, `core.hull.support_points`, else the eight corners of the bounds),
projected, fill FILL of the frame on the tighter axis and are centred on both: the object fills
the frame at any aspect ratio and from any angle. The
default angle (three-quarter, from above) is declared once, in core.options.RenderOptions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FILL = 0.85    # auto-framing: the projected object spans this fraction of the frame
MARGIN = 1.08  # sphere_distance: the bounding-sphere radius is scaled by this


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

    # basis and matrices are computed once per camera (a frame asks for them a dozen times)
    # and handed out read-only

    def _kept(self, name: str, make):
        value = self.__dict__.get(name)
        if value is None:
            value = make()
            for a in (value if isinstance(value, tuple) else (value,)):
                a.setflags(write=False)
            object.__setattr__(self, name, value)  # frozen: a cache, not a field
        return value

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors in world space."""
        def make():
            f = self.target - self.position
            f = f / np.linalg.norm(f)
            r = np.cross(f, self.up)
            r = r / np.linalg.norm(r)
            return r, np.cross(r, f), f
        return self._kept("_basis", make)

    def view_matrix(self) -> np.ndarray:
        def make():
            r, u, f = self.basis()
            m = np.eye(4)
            m[0, :3], m[1, :3], m[2, :3] = r, u, -f
            m[:3, 3] = -m[:3, :3] @ self.position
            return m
        return self._kept("_view", make)

    def projection_matrix(self) -> np.ndarray:
        """OpenGL perspective projection (depth -1..1 in NDC)."""
        def make():
            t = 1.0 / math.tan(math.radians(self.fov) / 2)
            n, f = self.near, self.far
            m = np.zeros((4, 4))
            m[0, 0] = t / self.aspect
            m[1, 1] = t
            m[2, 2] = (f + n) / (n - f)
            m[2, 3] = 2 * f * n / (n - f)
            m[3, 2] = -1.0
            return m
        return self._kept("_projection", make)

    def ray_directions(self) -> np.ndarray:
        """Unit world directions through pixel centres, H x W x 3, row 0 at the image top."""
        r, u, f = self.basis()
        th = math.tan(math.radians(self.fov) / 2)
        x = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * th * self.aspect
        y = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * th
        d = f + x[None, :, None] * r + y[:, None, None] * u
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def frame_bounds(bounds: np.ndarray, width: int, height: int, yaw: float = 0.0,
                 pitch: float = 0.0, fov: float = 40.0, distance: float | None = None,
                 target=None, points: np.ndarray | None = None) -> Camera:
    """Camera for world `bounds` (2 x 3) following the convention above; auto-framing fits
    `points` (K x 3, inside the bounds) when given, else the bounds' corners. A `target` away
    from the bounds centre frames the sphere about it that holds the whole bounding sphere."""
    lo, hi = np.asarray(bounds, np.float64)
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    center = (lo + hi) / 2
    if target is not None:
        target = np.asarray(target, np.float64)
        radius += float(np.linalg.norm(target - center))
        center = target
        if distance is None:
            half_v = math.radians(fov) / 2
            half_h = math.atan(math.tan(half_v) * width / height)
            distance = radius * MARGIN / math.sin(min(half_v, half_h))
    yaw_r = math.radians(yaw)
    pitch_r = math.radians(max(-89.9, min(89.9, pitch)))  # avoid a degenerate up vector
    offset = np.array([math.sin(yaw_r) * math.cos(pitch_r), math.sin(pitch_r),
                       math.cos(yaw_r) * math.cos(pitch_r)])
    if distance is None:
        if points is None:
            points = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                               for z in (lo[2], hi[2])])
        position = _fit_position(np.asarray(points, np.float64), -offset, width, height, fov)
        distance = float(np.dot(center - position, -offset))
        target = position - offset * distance
        if not distance > radius * 1.05:  # a point, or a very wide fov: frame the sphere
            distance = sphere_distance(bounds, width, height, fov)
            position, target = center + distance * offset, center
    else:
        distance = max(float(distance), 1e-6)
        position, target = center + distance * offset, center
    near = max(distance - radius * 1.05, radius * 1e-3, distance * 1e-4)
    # Far from a small object, distance +- radius rounds to one value: keep far beyond near.
    far = max(distance + radius * 1.05, near * (1 + 1e-6))
    return Camera(position=position, target=target, up=np.array([0.0, 1.0, 0.0]),
                  fov=fov, width=width, height=height, near=near, far=far)


def scene_camera(cam, bounds: np.ndarray, width: int, height: int) -> Camera:
    """A glTF camera (pipeline.scene.SceneCamera, looking down its local -Z, +Y up) as a
    Camera. Its yfov is kept and the output's aspect used (as viewers fit a window). An
    orthographic camera is approximated by a distant narrow perspective one with the same
    view height (ymag) at the scene. near/far cover the scene's bounds."""
    m = np.asarray(cam.matrix, np.float64)
    forward = -m[:3, 2] / max(float(np.linalg.norm(m[:3, 2])), 1e-12)
    up = m[:3, 1] / max(float(np.linalg.norm(m[:3, 1])), 1e-12)
    position = m[:3, 3].copy()
    lo, hi = np.asarray(bounds, np.float64)
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    centre = (lo + hi) / 2
    depth = float(np.dot(centre - position, forward))
    fov = math.degrees(cam.yfov)
    znear, zfar = cam.znear, cam.zfar
    if cam.type == "orthographic":
        back = 100.0 * max(cam.ymag, radius)
        position = position - forward * back
        depth += back
        znear, zfar = znear + back, zfar + back  # the clip planes stay where the asset put them
        fov = math.degrees(2 * math.atan(cam.ymag / max(depth, 1e-6)))
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    far = max(float(np.linalg.norm(corners - position, axis=1).max()) * 1.01, 1e-3)
    near = max(min(znear if znear > 0 else far * 1e-4, far * 0.5), far * 1e-6)
    if math.isfinite(zfar) and zfar > near:
        far = min(far, zfar)
    return Camera(position=position, target=position + forward * max(depth, radius), up=up,
                  fov=min(max(fov, 0.01), 179.0), width=width, height=height, near=near, far=far)
def _fit_position(corners: np.ndarray, forward: np.ndarray, width: int, height: int,
                  fov: float) -> np.ndarray:
    """Where a camera looking along `forward` sees the points fill FILL of the frame,
    centred. Per axis, a point p stays inside the frustum side planes when
    |(p - c).right| <= t (p - c).forward; the tightest corners fix the camera's sideways
    offset and its depth, and the tighter axis's depth wins (the other is then centred)."""
    up0 = np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up0)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    depth = corners @ forward
    t_v = math.tan(math.radians(fov) / 2) * FILL
    t_h = t_v * width / height
    sideways, depths = [], []
    for axis, t in ((right, t_h), (up, t_v)):
        a = corners @ axis
        hi_side, lo_side = np.max(a - t * depth), np.max(-a - t * depth)
        sideways.append((hi_side - lo_side) / 2)
        depths.append(-(hi_side + lo_side) / (2 * t))
    return sideways[0] * right + sideways[1] * up + min(depths) * forward


def sphere_distance(bounds: np.ndarray, width: int, height: int, fov: float = 40.0) -> float:
    """The distance at which the bounding sphere fills the frame with MARGIN (the framing the
    committed reference images were made with: bench.scenes passes it explicitly)."""
    lo, hi = np.asarray(bounds, np.float64)
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    half_v = math.radians(fov) / 2
    half_h = math.atan(math.tan(half_v) * width / height)
    return radius * MARGIN / math.sin(min(half_v, half_h))
