"""Decoding texture images from untrusted bytes, with the pixel count checked first."""
from __future__ import annotations

import contextlib
import io
import logging
import struct
import warnings

import numpy as np
from PIL import Image, JpegImagePlugin, PngImagePlugin, TgaImagePlugin, WebPImagePlugin  # noqa: F401  (FORMATS)

from core.errors import LimitExceeded, MalformedAsset
from core.scene import Sampler, Texture
from pipeline.limits import Limits

log = logging.getLogger(__name__)

FORMATS = ("PNG", "JPEG", "WEBP", "TGA")  # TGA: USD textures (UsdUVTexture reads it)
# Their plugins are imported above, which registers them: with a `formats` list naming one not
# registered (WEBP), Image.open would re-run Image.init() on every call (over 100 us each), and
# Image.init() imports every plugin Pillow has, a cost each cold process paid.


def decode_image(data: bytes | memoryview, source: str, limits: Limits) -> np.ndarray:
    """Decode PNG/JPEG/WebP/KTX2 (Basis Universal) bytes into an H x W x 4 uint8 array, row 0 at the top.

    The size is read from the header (Pillow opens lazily) and checked against
    `limits.max_texture_pixels` before any pixel is decoded, so a decompression bomb costs
    nothing. Raises MalformedAsset (not an image, truncated, unsupported format) or
    LimitExceeded, naming `source`.
    """
    if bytes(data[:12]) == KTX2_IDENTIFIER:
        return _decode_ktx2(data, source, limits)
    if bytes(data[:4]) == EXR_MAGIC:
        return _decode_exr(data, source, limits)
    with _pillow_errors(source):
        im = _open(data, source, limits)
        if im.mode.startswith("I"):  # 16-bit grey: convert() would clip it, not scale it
            grey = np.round(np.asarray(im, np.float64) / 257.0).clip(0, 255).astype(np.uint8)
            im = Image.fromarray(grey, "L")
        arr = np.asarray(im.convert("RGBA"), dtype=np.uint8)  # palette/grey/16-bit -> RGBA8
    if arr.ndim != 3 or arr.shape[2] != 4:
        raise MalformedAsset(source, f"image decoded to unexpected shape {arr.shape}")
    return np.ascontiguousarray(arr)


def probe_image(data: bytes | memoryview, source: str, limits: Limits) -> tuple[int, int]:
    """Check an encoded image without decoding its pixels: format, size against the limits,
    and that the stream is complete (PNG end chunk, JPEG end marker, WebP RIFF length), which
    catches truncation; damage inside the pixel data shows when the texture is decoded.
    Returns (width, height); raises MalformedAsset or LimitExceeded naming `source`."""
    head = bytes(data[:16])
    if head[:12] == KTX2_IDENTIFIER:
        return _open_ktx2(data, source, limits).level_size(0)
    if head[:4] == EXR_MAGIC:
        return _exr_size(data, source, limits)
    if head[:8] == PNG_SIGNATURE and head[12:] == b"IHDR" and len(data) >= 33:
        # PNG's size sits at a fixed place in IHDR: read it without Pillow (a third of ingest
        # time for a small asset); anything odd falls through to Pillow's full header parse.
        w, h, depth, colour = struct.unpack_from(">IIBB", data, 16)
        if depth in PNG_DEPTHS.get(colour, ()) and w > 0 and h > 0:
            _check_size(w, h, source, limits)
            _check_complete("PNG", data, source)
            return w, h
    with _pillow_errors(source):
        im = _open(data, source, limits)
    _check_complete(im.format, data, source)
    return im.size


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"


def _exr_size(data: bytes | memoryview, source: str, limits: Limits) -> tuple[int, int]:
    """An OpenEXR image's data window (header only), checked against the limits."""
    import OpenEXR  # here and in _decode_exr: only EXR textures need it
    try:
        header = OpenEXR.File(io.BytesIO(bytes(data)), header_only=True).header()
        (x0, y0), (x1, y1) = header["dataWindow"]
    except Exception as exc:  # the bindings raise RuntimeError / ValueError for broken files
        raise MalformedAsset(source, f"EXR image does not decode: {exc}") from None
    w, h = int(x1 - x0 + 1), int(y1 - y0 + 1)
    if w <= 0 or h <= 0:
        raise MalformedAsset(source, f"EXR data window is {w}x{h}")
    _check_size(w, h, source, limits)
    return w, h


def _decode_exr(data: bytes | memoryview, source: str, limits: Limits) -> np.ndarray:
    """An OpenEXR texture (PyPI `OpenEXR`) as RGBA8. Its linear values are sRGB-encoded (and
    clipped to 0..1): textures are held as 8-bit, and an EXR texture is mostly a colour map,
    which the renderer samples as sRGB; a data EXR (roughness, normals) reads off-curve."""
    w, h = _exr_size(data, source, limits)
    import OpenEXR
    try:
        channels = OpenEXR.File(io.BytesIO(bytes(data)), separate_channels=True).channels()
    except Exception as exc:
        raise MalformedAsset(source, f"EXR image does not decode: {exc}") from None
    planes = {name.split(".")[-1].upper(): ch.pixels for name, ch in channels.items()}
    rgb = [planes[c] for c in "RGB"] if all(c in planes for c in "RGB") else \
        [planes["Y"]] * 3 if "Y" in planes else None
    if rgb is None:
        raise MalformedAsset(source, f"EXR image has no R, G, B or Y channels "
                                     f"({', '.join(channels)})")
    alpha = planes.get("A", np.ones((h, w), np.float32))
    if any(p.shape != (h, w) for p in [*rgb, alpha]):
        raise MalformedAsset(source, "EXR image has subsampled channels")
    lin = np.nan_to_num(np.stack(rgb, axis=-1).astype(np.float32), nan=0.0, posinf=1.0)
    lin = np.clip(lin, 0.0, 1.0)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    a = np.clip(np.nan_to_num(alpha.astype(np.float32), nan=1.0), 0.0, 1.0)[..., None]
    return np.ascontiguousarray(np.round(np.concatenate([srgb, a], -1) * 255).astype(np.uint8))
KTX2_IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"


def _open_ktx2(data: bytes | memoryview, source: str, limits: Limits):
    """A Basis Universal KTX2 (KHR_texture_basisu) opened with opengl_basisu, its size checked
    from the header (pixelWidth/Height at bytes 20..28) before the transcoder parses it."""
    import opengl_basisu  # the Basis transcoder: only KTX2 textures need it

    if len(data) < 80:
        raise MalformedAsset(source, f"KTX2 image is truncated ({len(data)} bytes)")
    w, h = struct.unpack_from("<II", data, 20)
    _check_size(w, max(h, 1), source, limits)
    try:
        tex = opengl_basisu.open(bytes(data))
    except opengl_basisu.BasisuError as exc:  # UnsupportedError is a BasisuError
        raise MalformedAsset(source, f"KTX2 image does not decode: {exc}") from None
    if tex.faces != 1 or tex.codec.is_hdr:
        raise MalformedAsset(source, f"KTX2 image is a {'cube map' if tex.faces != 1 else 'HDR'} "
                                     "texture, not a 2D LDR one")
    _check_size(tex.width, tex.height, source, limits)
    return tex


def _decode_ktx2(data: bytes | memoryview, source: str, limits: Limits) -> np.ndarray:
    """KTX2 level 0 transcoded to RGBA8 (top row first, as KHR_texture_basisu requires)."""
    import opengl_basisu  # as in _open_ktx2

    tex = _open_ktx2(data, source, limits)
    try:
        image = tex.transcode("rgba8", level=0)
    except (opengl_basisu.BasisuError, IndexError) as exc:
        raise MalformedAsset(source, f"KTX2 image does not transcode: {exc}") from None
    return np.ascontiguousarray(image.data, np.uint8).reshape(image.height, image.width, 4)
PNG_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}


def _open(data: bytes | memoryview, source: str, limits: Limits) -> Image.Image:
    """Pillow's lazy open (header only), the size checked against our limit."""
    # Pillow's own bomb guard warns past MAX_IMAGE_PIXELS and fails past twice that; keep it
    # at least as high as ours so that ours, with its clearer message, decides.
    Image.MAX_IMAGE_PIXELS = max(Image.MAX_IMAGE_PIXELS or 0, limits.max_texture_pixels)
    im = Image.open(io.BytesIO(data), formats=FORMATS)
    _check_size(*im.size, source, limits)
    return im


def _check_size(w: int, h: int, source: str, limits: Limits) -> None:
    if w <= 0 or h <= 0:
        raise MalformedAsset(source, f"image has size {w}x{h}")
    if w * h > limits.max_texture_pixels:
        raise LimitExceeded(source, f"image is {w}x{h} = {w * h} pixels, over the limit of "
                                    f"{limits.max_texture_pixels} (ASSET_PREVIEW_MAX_TEXTURE_PIXELS)")


def _check_complete(fmt: str | None, data: bytes | memoryview, source: str) -> None:
    tail = bytes(data[-64:])  # `in` on a memoryview would look for one byte, not a sequence
    if fmt == "PNG" and b"IEND" not in tail[-16:]:
        raise MalformedAsset(source, "PNG image is truncated (no IEND chunk)")
    if fmt == "JPEG" and b"\xff\xd9" not in tail:
        raise MalformedAsset(source, "JPEG image is truncated (no end-of-image marker)")
    if fmt == "WEBP" and len(data) < 8 + int.from_bytes(bytes(data[4:8]), "little"):
        raise MalformedAsset(source, "WebP image is truncated")


@contextlib.contextmanager
def _pillow_errors(source: str):
    """Pillow's many exception types -> our MalformedAsset / LimitExceeded naming `source`."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    except (LimitExceeded, MalformedAsset):
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise LimitExceeded(source, f"image too large: {exc}") from None
    except Image.UnidentifiedImageError:
        raise MalformedAsset(source, "not a PNG, JPEG or WebP image") from None
    except (OSError, SyntaxError, ValueError, EOFError, MemoryError) as exc:
        raise MalformedAsset(source, f"image does not decode: {exc}") from None


class DeferredTexture(Texture):
    """A Texture whose pixels are decoded on first access to `.image`, then kept.

    Ingest probes the image (format, size, completeness) so a broken one is caught there and
    becomes a warning; decoding waits until something needs the pixels (a bake), so inspecting
    an asset or hashing it never pays for it. Behaves as a Texture otherwise (pickles too)."""
    _image: np.ndarray | None
    _data: bytes | memoryview | None

    def __init__(self, name: str, data: bytes | memoryview, size: tuple[int, int], limits: Limits,
                 sampler: Sampler | None = None, source: str = ""):
        self._data, self._limits, self.size = data, limits, size
        super().__init__(name=name, image=None, sampler=sampler or Sampler(), source=source)  # type: ignore[arg-type]  # decoded on first use

    @property
    def image(self) -> np.ndarray:
        if self._image is None:
            assert self._data is not None  # dropped only once decoded
            self._image = decode_image(self._data, self.source, self._limits)
            self._data = None
        return self._image

    @image.setter
    def image(self, value: np.ndarray | None) -> None:
        self._image = value

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        if isinstance(state.get("_data"), memoryview):  # a view into the asset file's bytes
            state["_data"] = bytes(state["_data"])
        return state

    def __repr__(self) -> str:
        state = "decoded" if self._image is not None else "not decoded yet"
        return f"DeferredTexture({self.name!r}, {self.size[0]}x{self.size[1]}, {state})"


# The names Hio's OpenEXR reader (the one Storm has without OpenImageIO) answers to a
# request for "worldtoscreen": the OpenEXR standard attribute is worldToNDC; the others are
# older spellings it also accepts (hio/OpenEXRImage.cpp, isWorldToNDC).
WORLD_TO_SCREEN_NAMES = ("worldtoscreen", "worldToScreen", "NP", "worldToNDC")


def world_to_screen(data: bytes | memoryview, source: str) -> tuple[np.ndarray | None, str]:
    """(the 4x4 `worldtoscreen` matrix of an image's metadata, row-major as USD's GfMatrix4d
    reads it, or None; why not when None). model:cardGeometry "fromTexture" places each card
    with it. Only OpenEXR headers carry it here, as for Storm built without OpenImageIO (its
    PNG/JPEG reader has no metadata); a matrix that does not invert is refused."""
    if bytes(data[:4]) != EXR_MAGIC:
        return None, "not an OpenEXR image (only EXR headers carry a worldtoscreen matrix here)"
    import OpenEXR
    try:
        header = OpenEXR.File(io.BytesIO(bytes(data)), header_only=True).header()
    except Exception as exc:  # the bindings raise RuntimeError / ValueError for broken files
        return None, f"EXR header does not decode: {exc}"
    for name in WORLD_TO_SCREEN_NAMES:
        value = header.get(name)
        if value is None:
            continue
        m = np.asarray(value, np.float64)
        if m.size != 16:
            return None, f"EXR attribute {name!r} holds {m.size} values, not a 4x4 matrix"
        m = m.reshape(4, 4)
        if not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
            return None, f"EXR attribute {name!r} is not an invertible matrix"
        return m, ""
    return None, "its EXR header has no worldtoscreen (worldToNDC) matrix"
