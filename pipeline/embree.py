"""Closest-hit ray casting through Embree 4, called directly (ctypes) on the library embreex ships.

Why not embreex's own classes: for the interior pass they cost more than the rays. Its
TriangleMesh copies the mesh in per-element loops (~1-2 µs a triangle, several times the BVH
build), while the pass casts about one ray per two triangles. Here the scene reads our numpy
arrays in place (shared buffers) and rays go in 16-wide packets (rtcIntersect16) from threads
over chunks: ctypes releases the GIL during each call, so both cores trace.

Same hits as embreex: the scene is ROBUST (as embreex's: without it rays grazing along an edge
slip through) and built at the default (medium, SAH) quality; the low-quality Morton builder
builds faster but misses those grazing hits. Results: the closest hit's distance, or inf.
"""
from __future__ import annotations

import ctypes
import glob
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_BUFFER_TYPE_INDEX, RTC_BUFFER_TYPE_VERTEX = 0, 1
RTC_FORMAT_UINT3, RTC_FORMAT_FLOAT3 = 0x5003, 0x9003
RTC_SCENE_FLAG_ROBUST = 1 << 2
RTC_INVALID_GEOMETRY_ID = 0xFFFFFFFF

# RTCRayHit16 (structure of arrays, 64-byte aligned): the ray's 12 fields, then the hit's
# Ng xyz, u, v, primID, geomID, instID[1] and, in builds with instance arrays, instPrimID[1].
PACKET = 16
_RAY_FIELDS = ("org_x", "org_y", "org_z", "tnear", "dir_x", "dir_y", "dir_z", "time",
               "tfar", "mask", "id", "flags")
_TFAR, _MASK = _RAY_FIELDS.index("tfar"), _RAY_FIELDS.index("mask")
_GEOM_ID = len(_RAY_FIELDS) + 6
_ROWS = len(_RAY_FIELDS) + 9  # one spare row for either hit layout
_CHUNK_PACKETS = 256  # packets per thread task: enough work per task to amortise its start

_lib = None
_device = None
_device_pid = 0
_lock = threading.Lock()


def _library() -> ctypes.CDLL:
    """libembree4 as bundled in the embreex wheel (its .libs folder), else the system's."""
    global _lib
    if _lib is None:
        import embreex
        here = os.path.dirname(embreex.__file__)
        found = sorted(glob.glob(os.path.join(here, os.pardir, "embreex.libs", "libembree4*.so*")))
        lib = ctypes.CDLL(found[0] if found else "libembree4.so.4")
        vp, u = ctypes.c_void_p, ctypes.c_uint
        for name, res, args in (
                ("rtcNewDevice", vp, [ctypes.c_char_p]),
                ("rtcGetDeviceError", ctypes.c_int, [vp]),
                ("rtcNewScene", vp, [vp]),
                ("rtcSetSceneFlags", None, [vp, ctypes.c_int]),
                ("rtcNewGeometry", vp, [vp, ctypes.c_int]),
                ("rtcSetSharedGeometryBuffer", None, [vp, ctypes.c_int, u, ctypes.c_int, vp,
                                                      ctypes.c_size_t, ctypes.c_size_t, ctypes.c_size_t]),
                ("rtcCommitGeometry", None, [vp]),
                ("rtcAttachGeometry", u, [vp, vp]),
                ("rtcReleaseGeometry", None, [vp]),
                ("rtcCommitScene", None, [vp]),
                ("rtcReleaseScene", None, [vp]),
                ("rtcIntersect8", None, [vp, vp, vp, vp]),
                ("rtcIntersect16", None, [vp, vp, vp, vp])):
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
        _lib = lib
    return _lib


def _get_device():
    """One Embree device per process (a forked child gets its own: the parent's thread pool
    does not survive a fork)."""
    global _device, _device_pid
    with _lock:
        if _device is None or _device_pid != os.getpid():
            _pools.clear()
            _device_pid = os.getpid()
            lib = _library()
            _device = lib.rtcNewDevice(None)
            if not _device:
                raise RuntimeError("Embree: rtcNewDevice failed")
    return _device


class TriangleScene:
    """A committed Embree scene over one triangle mesh; `closest(origins, directions)`."""

    def __init__(self, positions: np.ndarray, triangles: np.ndarray):
        lib, dev = _library(), _get_device()
        # Embree reads vertices with 16-byte loads: one padding vertex past the end.
        self._vertices = np.zeros((len(positions) + 1, 3), np.float32)
        self._vertices[:-1] = positions
        self._indices = np.ascontiguousarray(triangles, np.uint32).reshape(-1, 3)
        self._scene = lib.rtcNewScene(dev)
        lib.rtcSetSceneFlags(self._scene, RTC_SCENE_FLAG_ROBUST)
        if len(self._indices):
            geom = lib.rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE)
            lib.rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                           self._vertices.ctypes.data, 0, 12, len(positions))
            lib.rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           self._indices.ctypes.data, 0, 12, len(self._indices))
            lib.rtcCommitGeometry(geom)
            lib.rtcAttachGeometry(self._scene, geom)
            lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self._scene)
        err = lib.rtcGetDeviceError(dev)
        if err:
            raise RuntimeError(f"Embree: scene build failed (error {err})")

    def closest(self, origins: np.ndarray, directions: np.ndarray, threads: int | None = None) -> np.ndarray:
        """Distance to the closest hit along each ray (tnear 0), inf where it misses."""
        n = len(origins)
        packets = -(-n // PACKET)
        buf = _aligned_words(packets * _ROWS * PACKET).reshape(packets, _ROWS, PACKET)
        f = buf.view(np.float32)
        flat = np.zeros((packets * PACKET, 6), np.float32)  # tail lanes: zero rays, ignored
        flat[:n, :3], flat[:n, 3:] = origins, directions
        lanes = flat.reshape(packets, PACKET, 6)
        for axis in range(3):
            f[:, axis] = lanes[..., axis]
            f[:, 4 + axis] = lanes[..., 3 + axis]
        f[:, _TFAR] = np.inf
        buf[:, _MASK] = 0xFFFFFFFF
        buf[:, _GEOM_ID:] = RTC_INVALID_GEOMETRY_ID
        valid = _aligned_words(PACKET)
        valid[:] = 0xFFFFFFFF  # -1: every lane active (tail lanes trace a zero ray, ignored)
        lib, scene, stride = _library(), self._scene, buf.strides[0]
        intersect = getattr(lib, f"rtcIntersect{PACKET}")
        base, vptr = buf.ctypes.data, valid.ctypes.data

        def trace(first: int) -> None:
            for k in range(first, min(first + _CHUNK_PACKETS, packets)):
                intersect(vptr, scene, base + k * stride, None)

        starts = range(0, packets, _CHUNK_PACKETS)
        workers = threads or os.cpu_count() or 1
        if workers > 1 and len(starts) > 1:
            list(_pool(workers).map(trace, starts))
        else:
            for s in starts:
                trace(s)
        t = f[:, _TFAR].reshape(-1)[:n].copy()
        t[buf[:, _GEOM_ID].reshape(-1)[:n] == RTC_INVALID_GEOMETRY_ID] = np.inf
        return t

    def __del__(self):
        if getattr(self, "_scene", None) and _lib is not None:
            _lib.rtcReleaseScene(self._scene)
            self._scene = None


_pools: dict[int, ThreadPoolExecutor] = {}


def _pool(workers: int) -> ThreadPoolExecutor:
    _get_device()  # drops pools inherited through a fork
    with _lock:
        if workers not in _pools:
            _pools[workers] = ThreadPoolExecutor(workers, thread_name_prefix="embree")
        return _pools[workers]


def _aligned_words(count: int) -> np.ndarray:
    """uint32 array of `count` words starting on a 64-byte boundary (packets need it)."""
    raw = np.zeros(count + 16, np.uint32)  # tnear, time, id, flags: 0
    skip = (-raw.ctypes.data % 64) // 4
    return raw[skip:skip + count]
