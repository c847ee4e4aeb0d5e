"""A rendered image: linear radiance for measurement, tone-mapped sRGB for people, and encoders.

Tone mapping and sRGB encoding normally run on the GPU in the final pass (renderer.raster.final);
`tonemap_srgb8` is the same arithmetic in numpy, used for frames made elsewhere (the ray
tracer, the reference) so every path shows an image the same way.
"""
from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from isal import isal_zlib
from PIL import Image

from core.colour import srgb_encode

log = logging.getLogger(__name__)

_PIL_FORMATS = {"png": "PNG", "jpeg": "JPEG", "jpg": "JPEG", "webp": "WEBP"}
# WebP for thumbnails (stills and turntables): method 0 is libwebp's fastest effort (2-3x faster
# than the default 4, ~15% larger). Lossy alpha at 70 quantises the alpha plane before its
# lossless coding: at 512 px an RGBA Duck encodes in 6.8 ms instead of 11.8 at half the bytes,
# alpha within 10/255 (mean 1.2/255) of the frame's; lossy colour is WebP's contract already.
WEBP_SETTINGS = {"method": 0, "alpha_quality": 70}


@dataclass(frozen=True)
class FrameTimings:
    """Where a frame's time went: the stages differ by method (raster: upload, draw, finish;
    raytrace: build, trace, tonemap), the total is always there."""
    total_ms: float
    stages_ms: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        return {**{k + "_ms": v for k, v in self.stages_ms.items()}, "total_ms": self.total_ms}


class Frame:
    """One rendered image. `linear` may be given as a function that reads it when first asked
    for (renderer.raster.final: a thumbnail never needs it, so its final pass does not draw it)."""

    def __init__(self, linear: np.ndarray | Callable[[], np.ndarray], rgba8: np.ndarray,
                 plan: dict | None = None, timings: FrameTimings | None = None,
                 alpha_is_mask: bool = False):
        self._linear = linear
        self.rgba8 = rgba8  # H x W x 4 uint8: tone-mapped sRGB, straight alpha
        self.plan = {} if plan is None else plan      # what ran and why
        self.timings = FrameTimings(0.0) if timings is None else timings
        # alpha=coverage over a background: the colour already holds the background and alpha
        # is only the object's mask (so a format without alpha keeps the colour as it is)
        self.alpha_is_mask = alpha_is_mask

    @property
    def linear(self) -> np.ndarray:
        """H x W x 4 float32: linear radiance (premultiplied by alpha), alpha."""
        if not isinstance(self._linear, np.ndarray):
            self._linear = self._linear()
        return self._linear

    @property
    def width(self) -> int:
        return int(self.rgba8.shape[1])

    @property
    def height(self) -> int:
        return int(self.rgba8.shape[0])

    def encode(self, fmt: str = "png", quality: int | None = None) -> bytes:
        """PNG (lossless, alpha), JPEG (no alpha: composited over black) or WebP bytes."""
        key = fmt.lower().lstrip(".")
        if key not in _PIL_FORMATS:
            raise ValueError(f"unknown image format {fmt!r}: use png, jpeg or webp")
        opaque = bool(np.all(self.rgba8[..., 3] == 255))
        if key == "png":
            return encode_png(self.rgba8[..., :3] if opaque else self.rgba8)
        if _PIL_FORMATS[key] == "JPEG" or opaque:
            rgb = self.rgba8[..., :3]
            if not opaque and not self.alpha_is_mask:  # JPEG has no alpha: onto black
                rgb = (rgb.astype(np.uint16) * self.rgba8[..., 3:4] // 255).astype(np.uint8)
            img = Image.fromarray(np.ascontiguousarray(rgb), "RGB")
        else:
            img = Image.fromarray(self.rgba8, "RGBA")
        buf = io.BytesIO()
        kwargs: dict = {"quality": int(quality if quality is not None else 90)}
        if _PIL_FORMATS[key] == "WEBP":
            kwargs.update(WEBP_SETTINGS)
        img.save(buf, _PIL_FORMATS[key], **kwargs)
        return buf.getvalue()

    def save(self, path: str | os.PathLike, quality: int | None = None) -> None:
        """Write by extension: .png .jpg/.jpeg .webp (tone-mapped), .npy or .exr (linear)."""
        path = os.fspath(path)
        ext = os.path.splitext(path)[1].lower().lstrip(".")
        if ext == "npy":
            np.save(path, self.linear.astype(np.float32, copy=False))
        elif ext == "exr":
            write_exr(path, self.linear)
        elif ext in _PIL_FORMATS:
            data = self.encode(ext, quality)
            with open(path, "wb") as f:
                f.write(data)
        else:
            raise ValueError(f"{path}: unknown output extension (png, jpg, webp, npy, exr)")


def encode_png(pixels: np.ndarray) -> bytes:
    """H x W x 3 (RGB) or 4 (RGBA) uint8 as an 8-bit PNG, for thumbnails: every row with the
    Sub filter (vectorised here; Pillow's adaptive filtering costs more than it saves at this
    size) and deflated by ISA-L at level 1, faster than Pillow's compress_level=1 for a
    slightly smaller file (README: Encoding)."""
    h, w, c = pixels.shape
    rows = np.ascontiguousarray(pixels, np.uint8).reshape(h, w * c)
    filtered = np.empty((h, w * c + 1), np.uint8)
    filtered[:, 0] = 1  # filter type Sub: each byte minus the same channel of the pixel left
    filtered[:, 1:c + 1] = rows[:, :c]
    np.subtract(rows[:, c:], rows[:, :-c], out=filtered[:, c + 1:])
    header = struct.pack(">IIBBBBB", w, h, 8, {3: 2, 4: 6}[c], 0, 0, 0)
    return b"".join((b"\x89PNG\r\n\x1a\n", _png_chunk(b"IHDR", header),
                     _png_chunk(b"IDAT", isal_zlib.compress(filtered.reshape(-1).data, 1)), _png_chunk(b"IEND", b"")))


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(tag)))


def alpha_is_mask(options) -> bool:
    """RenderOptions alpha=coverage over an environment or colour: see Frame.alpha_is_mask."""
    return options.alpha == "coverage" and options.background != "transparent"


def write_exr(path: str, linear: np.ndarray) -> None:
    """Linear float32 RGBA OpenEXR (PyPI `OpenEXR`, ZIP compression)."""
    import OpenEXR  # only EXR output loads it (a C extension of its own)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {"RGBA": np.ascontiguousarray(linear, dtype=np.float32)}
    with OpenEXR.File(header, channels) as f:
        f.write(path)


# --- the numpy twin of shaders/final.frag's tone mapping --------------------------------------

MAX_EXPOSURE = 64.0  # stops either way; beyond it 2**EV overflows float32 (and Python floats)


def exposure_scale(exposure: float) -> float:
    """2**exposure with the exposure clamped to +-MAX_EXPOSURE (the GPU pass uses it too)."""
    return float(2.0 ** max(min(exposure, MAX_EXPOSURE), -MAX_EXPOSURE))


def tonemap(rgb: np.ndarray, method: str = "neutral", exposure: float = 0.0) -> np.ndarray:
    """Linear radiance -> display-referred linear [0, 1] (before the sRGB transfer)."""
    c = np.maximum(rgb * np.float32(exposure_scale(exposure)), 0).astype(np.float32)
    if method == "none":
        return np.clip(c, 0, 1)
    if method == "aces":
        return _aces_hill(c)
    if method == "neutral":
        return _pbr_neutral(c)
    raise ValueError(f"unknown tone mapping {method!r}: use neutral, aces or none")


def _pbr_neutral(c: np.ndarray) -> np.ndarray:
    # Khronos PBR Neutral (github.com/KhronosGroup/ToneMapping, PBR_Neutral).
    start, desat = 0.8 - 0.04, 0.15
    x = c.min(axis=-1, keepdims=True)
    offset = np.where(x < 0.08, x - 6.25 * x * x, 0.04)
    c = c - offset
    peak = c.max(axis=-1, keepdims=True)
    d = 1.0 - start
    new_peak = 1.0 - d * d / (peak + d - start)
    scaled = c * (new_peak / np.maximum(peak, 1e-12))
    g = 1.0 - 1.0 / (desat * (peak - new_peak) + 1.0)
    mapped = scaled * (1 - g) + new_peak * g
    return np.clip(np.where(peak < start, c, mapped), 0, 1)


_ACES_IN = np.array([[0.59719, 0.35458, 0.04823], [0.07600, 0.90834, 0.01566],
                     [0.02840, 0.13383, 0.83777]], np.float32)
_ACES_OUT = np.array([[1.60475, -0.53108, -0.07367], [-0.10208, 1.10813, -0.00605],
                      [-0.00327, -0.07276, 1.07602]], np.float32)


def _aces_hill(c: np.ndarray) -> np.ndarray:
    # Stephen Hill's RRT+ODT fit, with the 1/0.6 exposure bias the glTF Sample Viewer uses.
    c = (c / 0.6) @ _ACES_IN.T
    c = (c * (c + 0.0245786) - 0.000090537) / (c * (0.983729 * c + 0.4329510) + 0.238081)
    return np.clip(c @ _ACES_OUT.T, 0, 1)


def tonemap_srgb8(linear: np.ndarray, method: str = "neutral", exposure: float = 0.0,
                  background=None) -> np.ndarray:
    """Premultiplied linear RGBA -> straight-alpha sRGB uint8, optionally composited over an
    sRGB `background` colour (0..1; or an H x 1 x 3 column of them, the gradient) in display
    space, as the GPU pass does."""
    a = linear[..., 3:4]
    rgb = linear[..., :3] / np.maximum(a, 1e-6)
    out = srgb_encode(tonemap(rgb, method, exposure))
    if background is not None:
        out = out * a + np.asarray(background, np.float32) * (1 - a)
        a = np.ones_like(a)
    return np.round(np.concatenate([out, a], axis=-1) * 255).clip(0, 255).astype(np.uint8)
