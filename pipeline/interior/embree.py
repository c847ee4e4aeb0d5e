"""Closest-hit ray casting through Embree 4, called directly (ctypes) on the library embreex ships.

Why not embreex's own classes: for the interior pass they cost more than the rays. Its
TriangleMesh copies the mesh in per-element loops (slower than the BVH build), while the
pass casts about one ray per two triangles. Here the scene reads our numpy
arrays in place (shared buffers) and rays go in 16-wide packets (rtcIntersect16): per span of
packets one compiled loop (numba, no GIL) fills them and another traces them, the spans taken
in turn by the calling thread and a pool thread, so both cores trace.

The hits are embreex's, up to float rounding: the scene is ROBUST (as embreex's: without it
rays grazing an edge slip through) and
its BVH is built by the SAH builder at medium quality, BVH8. Over quads (pipeline.interior.pairing:
the mesh's own triangles, two to a quad) that build is faster than embreex's triangle build,
and the build is most of the pass on a large mesh (figures: README, bench bake). What
changes is only what float rounding already decides: a ray running within a face's plane (the
flat panels of CesiumMilkTruck) is kept or lost by a last-bit difference, and on the truck
every vertex the quads move is one that a one-ulp nudge of the positions moves in embreex's
triangle pass too (tests/test_interior.py). Rejected by the same measurement: the Morton
builder (faster to build, slower to trace) loses every corner ray of an axis-aligned split
cube; the two-level (low quality) scene loses them too; non-robust leaves lose thousands of
rays; compact (index) leaves and a BVH4 build no faster. Results: the closest hit's distance,
or inf.
"""
from __future__ import annotations

import ctypes
import glob
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

RTC_GEOMETRY_TYPE_QUAD = 1
RTC_BUFFER_TYPE_INDEX, RTC_BUFFER_TYPE_VERTEX = 0, 1
RTC_FORMAT_UINT4, RTC_FORMAT_FLOAT3 = 0x5004, 0x9003
RTC_SCENE_FLAG_ROBUST = 1 << 2
RTC_BUILD_QUALITY_MEDIUM = 1
RTC_INVALID_GEOMETRY_ID = 0xFFFFFFFF

# RTCRayHit16 (structure of arrays, 64-byte aligned): the ray's 12 fields, then the hit's
# Ng xyz, u, v, primID, geomID, instID[1] and, in builds with instance arrays, instPrimID[1].
PACKET = 16
_RAY_FIELDS = ("org_x", "org_y", "org_z", "tnear", "dir_x", "dir_y", "dir_z", "time",
               "tfar", "mask", "id", "flags")
_TFAR, _MASK = _RAY_FIELDS.index("tfar"), _RAY_FIELDS.index("mask")
_GEOM_ID = len(_RAY_FIELDS) + 6
_ROWS = len(_RAY_FIELDS) + 9  # one spare row for either hit layout
_SPAN = 64  # packets per thread task (1024 rays, ~0.35 ms): amortises the hand-off

_CORES = os.cpu_count() or 1  # read once: os.cpu_count() reads a file on each call
_lib = None
_device = None
_device_pid = 0
_lock = threading.Lock()


def _library() -> ctypes.CDLL:
    """libembree4 as bundled in the embreex wheel (its .libs folder), else the system's."""
    global _lib
    if _lib is None:
        import embreex  # only to find its bundled library, on first use
        here = os.path.dirname(embreex.__file__)
        found = sorted(glob.glob(os.path.join(here, os.pardir, "embreex.libs", "libembree4*.so*")))
        lib = ctypes.CDLL(found[0] if found else "libembree4.so.4")
        vp, u = ctypes.c_void_p, ctypes.c_uint
        for name, res, args in (
                ("rtcNewDevice", vp, [ctypes.c_char_p]),
                ("rtcGetDeviceError", ctypes.c_int, [vp]),
                ("rtcNewScene", vp, [vp]),
                ("rtcSetSceneFlags", None, [vp, ctypes.c_int]),
                ("rtcSetSceneBuildQuality", None, [vp, ctypes.c_int]),
                ("rtcNewGeometry", vp, [vp, ctypes.c_int]),
                ("rtcSetSharedGeometryBuffer", None, [vp, ctypes.c_int, u, ctypes.c_int, vp,
                                                      ctypes.c_size_t, ctypes.c_size_t, ctypes.c_size_t]),
                ("rtcCommitGeometry", None, [vp]),
                ("rtcAttachGeometry", u, [vp, vp]),
                ("rtcReleaseGeometry", None, [vp]),
                ("rtcCommitScene", None, [vp]),
                ("rtcReleaseScene", None, [vp]),
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
            _device = lib.rtcNewDevice(None)  # default: TBB builds on every core
            if not _device:
                raise RuntimeError("Embree: rtcNewDevice failed")
    return _device


class TriangleScene:
    """A committed Embree scene over one triangle mesh, given as the quads that
    pipeline.interior.pairing.pair_quads makes of its triangles; `closest(points, directions, offsets, select)`."""

    def __init__(self, positions: np.ndarray, quads: np.ndarray):
        lib, dev = _library(), _get_device()
        # Embree reads vertices with 16-byte loads: one padding vertex past the end.
        self._vertices = np.zeros((len(positions) + 1, 3), np.float32)
        self._vertices[:-1] = positions
        # Quads: the same surface as the triangles in half the primitives for the SAH build,
        # which is most of the interior pass on a big mesh.
        self._indices = np.ascontiguousarray(quads, np.uint32).reshape(-1, 4)
        self._scene = lib.rtcNewScene(dev)
        lib.rtcSetSceneFlags(self._scene, RTC_SCENE_FLAG_ROBUST)
        lib.rtcSetSceneBuildQuality(self._scene, RTC_BUILD_QUALITY_MEDIUM)
        if len(self._indices):
            geom = lib.rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_QUAD)
            lib.rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                           self._vertices.ctypes.data, 0, 12, len(positions))
            lib.rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4,
                                           self._indices.ctypes.data, 0, 16, len(self._indices))
            lib.rtcCommitGeometry(geom)
            lib.rtcAttachGeometry(self._scene, geom)
            lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self._scene)
        err = lib.rtcGetDeviceError(dev)
        if err:
            raise RuntimeError(f"Embree: scene build failed (error {err})")

    def closest(self, points: np.ndarray, directions: np.ndarray, offsets: np.ndarray,
                select: np.ndarray, threads: int | None = None, normals: bool = False):
        """Distance to the closest hit along each ray (tnear 0), inf where it misses: ray k
        starts at points[v] + offsets[v] * directions[v] and runs along directions[v], for
        v = select[k] ((n, 3) float32 rows, (n,) offsets).

        Each task fills its own packets (a compiled loop, _fill) and traces them, so the set-up
        is spread over the cores too (through numpy it was a tenth of the trace). With
        `normals`, also each hit's unnormalised geometric normal ((n, 3), Embree's: the cross
        product of the triangle's edges v1 - v0 and v2 - v0) and the quad hit ((n,) int64);
        both undefined where the ray missed."""
        n = len(select)
        packets = -(-n // PACKET)
        buf = _aligned_words(packets * _ROWS * PACKET, zeroed=False).reshape(packets, _ROWS, PACKET)
        f = buf.view(np.float32)
        # Lane masks: -1 traces the lane. The last packet's unused lanes are switched off.
        valid = _aligned_words(2 * PACKET).reshape(2, PACKET)
        valid[0] = 0xFFFFFFFF
        valid[1, :n - (packets - 1) * PACKET] = 0xFFFFFFFF
        intersect16, scene, stride = _intersect16_function(), self._scene, buf.strides[0]
        base, every, last = buf.ctypes.data, valid[0].ctypes.data, valid[1].ctypes.data
        sel = np.ascontiguousarray(select, np.int64)

        def trace(span: range) -> None:
            _fill(f, buf, points, directions, offsets, sel, span.start, span.stop)
            _trace_packets(intersect16, every, last, scene, base, stride, span.start, span.stop, packets)

        # A few spans per thread, taken in turn by this thread and workers-1 pool threads (the
        # compiled loops hold no GIL, so they trace in parallel); several spans each balance a
        # core that another process slows.
        workers = min(threads or _CORES, -(-packets // _SPAN))
        spans = iter([range(a, min(a + _SPAN, packets)) for a in range(0, packets, _SPAN)])

        def work() -> None:
            for span in spans:  # a list iterator's next() is atomic under the GIL
                trace(span)

        helpers = [_pool(workers - 1).submit(work) for _ in range(workers - 1)]
        work()
        for helper in helpers:
            helper.result()
        tfar = f[:, _TFAR].reshape(-1)[:n].copy()  # tfar stays inf where the ray misses
        if normals:
            ng = f[:, len(_RAY_FIELDS):len(_RAY_FIELDS) + 3].transpose(0, 2, 1).reshape(-1, 3)[:n].copy()
            prim = buf[:, _GEOM_ID - 1].reshape(-1)[:n].astype(np.int64)
            return tfar, ng, prim
        return tfar

    def __del__(self):
        if getattr(self, "_scene", None) and _lib is not None:
            _lib.rtcReleaseScene(self._scene)
            self._scene = None


@njit(cache=True, nogil=True)
def _fill(f, u, points, directions, offsets, select, first, stop):
    """Every field of packets first..stop-1 of the buffer (f and u: its float and word views,
    uninitialised) from the rays select[first * PACKET:]; lanes past the last ray are zeros."""
    for packet in range(first, stop):
        u[packet] = 0
        for lane in range(PACKET):
            k = packet * PACKET + lane
            if k >= len(select):
                continue
            v = select[k]
            for axis in range(3):
                d = directions[v, axis]
                f[packet, axis, lane] = points[v, axis] + d * offsets[v]
                f[packet, 4 + axis, lane] = d
            f[packet, _TFAR, lane] = np.inf
            u[packet, _MASK, lane] = 0xFFFFFFFF
            for row in range(_GEOM_ID, _ROWS):
                u[packet, row, lane] = RTC_INVALID_GEOMETRY_ID


@njit(cache=True, nogil=True)
def _trace_packets(intersect16, every, last, scene, base, stride, first, stop, packets):
    """Packets first..stop-1 traced by rtcIntersect16 (a ctypes function, passed in), without
    the GIL; the last packet has its own lane mask.

    Why not a ctypes call per packet from each thread: every call gives up and takes back the
    GIL, and the threads' hand-offs serialise them: two threads traced no faster than one. The
    function comes as an argument, not as a global, so that numba can cache the loop (an
    address compiled in cannot be: each process would compile it again)."""
    for k in range(first, stop):
        intersect16(every if k < packets - 1 else last, scene, base + k * stride, 0)


_intersect16 = None


def _intersect16_function():
    """rtcIntersect16 as a ctypes function that compiled code can call."""
    global _intersect16
    with _lock:
        if _intersect16 is None:
            vp = ctypes.c_void_p
            proto = ctypes.CFUNCTYPE(None, vp, vp, vp, vp)
            address = ctypes.cast(_library().rtcIntersect16, vp).value
            assert address is not None  # the symbol was resolved when the library loaded
            _intersect16 = proto(address)
    return _intersect16


_pools: dict[int, ThreadPoolExecutor] = {}


def spare_thread() -> ThreadPoolExecutor | None:
    """The pass's pool thread for other work before the trace (pipeline.interior.pairing), or None
    on one core."""
    return _pool(1) if _CORES > 1 else None


def _pool(workers: int) -> ThreadPoolExecutor:
    _get_device()  # drops pools inherited through a fork
    with _lock:
        if workers not in _pools:
            _pools[workers] = ThreadPoolExecutor(workers, thread_name_prefix="embree")
        return _pools[workers]


def _aligned_words(count: int, zeroed: bool = True) -> np.ndarray:
    """uint32 array of `count` words starting on a 64-byte boundary (packets need it)."""
    raw = (np.zeros if zeroed else np.empty)(count + 16, np.uint32)
    skip = (-raw.ctypes.data % 64) // 4
    return raw[skip:skip + count]
