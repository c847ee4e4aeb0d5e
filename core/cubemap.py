"""Direction conventions shared by the bake, the renderer, the ray tracer and the reference.

Cube faces are stored in OpenGL order +X, -X, +Y, -Y, +Z, -Z; each face is S x S with row 0 at
t = 0 of the OpenGL cube-map face table (so arrays upload to GL unchanged).

Equirectangular panoramas use Mitsuba's `envmap` convention so the reference renderer needs
no rotation: a world direction (x, y, z), +Y up, maps to
    u = 0.5 + atan2(-x, z) / 2pi,   v = acos(y) / pi
with u across the image from the left edge and v down from the top row. So the panorama's
centre column looks toward +Z, u = 0.25 toward +X, and the top row is straight up.
"""
from __future__ import annotations

import math

import numpy as np

# (major axis, sign, sc axis & sign, tc axis & sign) per face, from the OpenGL spec's table.
_FACES: list[tuple[int, int, tuple[int, int], tuple[int, int]]] = [
    (0, +1, (2, -1), (1, -1)),  # +X: sc = -z, tc = -y
    (0, -1, (2, +1), (1, -1)),  # -X: sc = +z, tc = -y
    (1, +1, (0, +1), (2, +1)),  # +Y: sc = +x, tc = +z
    (1, -1, (0, +1), (2, -1)),  # -Y: sc = +x, tc = -z
    (2, +1, (0, +1), (1, -1)),  # +Z: sc = +x, tc = -y
    (2, -1, (0, -1), (1, -1)),  # -Z: sc = -x, tc = -y
]
_S_AXIS, _S_SIGN, _T_AXIS, _T_SIGN = (np.array([(f[2], f[3])[i][j] for f in _FACES])
                                      for i in (0, 1) for j in (0, 1))


def env_rotation_matrix(degrees: float) -> np.ndarray:
    """World -> environment directions for an environment turned `degrees` about +Y
    (right-handed: what was at +Z moves toward +X). Lookups apply it before sampling."""
    t = math.radians(degrees)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def equirect_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (..., 3) -> panorama (u, v) in [0, 1]."""
    u = 0.5 + np.arctan2(-d[..., 0], d[..., 2]) / (2 * np.pi)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return u % 1.0, v


def equirect_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Inverse of `equirect_uv`."""
    phi = (u - 0.5) * 2 * np.pi
    theta = v * np.pi
    s = np.sin(theta)
    return np.stack([-np.sin(phi) * s, np.cos(theta), np.cos(phi) * s], axis=-1)


def sample_equirect(image: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an H x W x C panorama in directions d (..., 3); wraps in u."""
    h, w = image.shape[:2]
    u, v = equirect_uv(d)
    x = u * w - 0.5
    y = np.clip(v * h - 0.5, 0, h - 1)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    x0 %= w
    x1 = (x0 + 1) % w
    y1 = np.minimum(y0 + 1, h - 1)
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def face_points(coords: np.ndarray) -> np.ndarray:
    """Directions (not normalized: the major axis is +-1) at face coordinates sc, tc in
    coords x coords (each -1..1) on every face: 6 x K x K x 3, row index t, column s."""
    tc, sc = np.meshgrid(coords, coords, indexing="ij")
    out = np.empty((6, len(coords), len(coords), 3))
    for f, (major, sign, (sa, ss), (ta, ts)) in enumerate(_FACES):
        out[f, ..., major] = sign
        out[f, ..., sa] = ss * sc
        out[f, ..., ta] = ts * tc
    return out


def face_directions(size: int) -> np.ndarray:
    """Unit directions through the texel centres of every face: 6 x S x S x 3."""
    out = face_points((np.arange(size) + 0.5) / size * 2 - 1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def direction_to_face(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directions (..., 3) -> (face index, s, t) with s, t in [0, 1]."""
    a = np.abs(d)
    major = np.argmax(a, axis=-1)
    m = np.take_along_axis(d, major[..., None], axis=-1)[..., 0]
    face = major * 2 + (m < 0)
    ma = np.abs(m)
    # Per face: the axis and sign of s and of t, gathered per direction (no loop over faces).
    s = (_S_SIGN[face] * np.take_along_axis(d, _S_AXIS[face][..., None], axis=-1)[..., 0]) / ma
    t = (_T_SIGN[face] * np.take_along_axis(d, _T_AXIS[face][..., None], axis=-1)[..., 0]) / ma
    return face, (s + 1) / 2, (t + 1) / 2


def sample_cube(faces: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear lookup (clamped at face edges) of 6 x S x S x C faces in directions (..., 3)."""
    size = faces.shape[1]
    face, s, t = direction_to_face(d)
    x = np.clip(s * size - 0.5, 0, size - 1)
    y = np.clip(t * size - 0.5, 0, size - 1)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    x1 = np.minimum(x0 + 1, size - 1)
    y1 = np.minimum(y0 + 1, size - 1)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    f = faces.astype(np.float32, copy=False).reshape(6 * size * size, -1)
    row0, row1 = (face * size + y0) * size, (face * size + y1) * size  # flat texel indices
    top = f[row0 + x0] * (1 - fx) + f[row0 + x1] * fx
    bottom = f[row1 + x0] * (1 - fx) + f[row1 + x1] * fx
    return (top * (1 - fy) + bottom * fy).reshape(*d.shape[:-1], *faces.shape[3:])


# --- sizes of baked environment cubemaps ----------------------------------------------------

DEFAULT_FACE_SIZE = 256  # environment cube faces of a bake that names no size (asset-bake, uploads)
MIN_FACE = 4             # smallest mip face; rougher lobes need no finer than this, see default_levels
MAX_FACE = 2048


def default_face_size(thumbnail_px: int) -> int:
    """Cube face size for thumbnails of `thumbnail_px`: the power of two >= it, in [32, 512].
    A background spanning ~60 degrees over the thumbnail wants about 1.5 px per pixel per 90
    degrees; past 512 the bundled 1024 x 512 panoramas (256 px per 90 degrees) have no detail."""
    return int(min(512, max(32, 1 << max(0, int(thumbnail_px) - 1).bit_length())))


def check_face_size(face_size: int) -> None:
    """ValueError unless `face_size` is a power of two no larger than MAX_FACE."""
    if face_size < 1 or face_size & (face_size - 1) or face_size > MAX_FACE:
        raise ValueError(f"face_size must be a power of two <= {MAX_FACE}, got {face_size}")


def default_levels(face_size: int) -> int:
    """Mips from face_size down to MIN_FACE (4 px): log2(face_size) - 1 levels (7 for 256).
    Faces of 2 or 1 px cannot hold a roughness-1 lobe across a face without visible steps."""
    return max(1, int(math.log2(face_size)) - int(math.log2(MIN_FACE)) + 1)
