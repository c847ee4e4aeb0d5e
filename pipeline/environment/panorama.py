"""Equirectangular panoramas: loading (.jpg/.png sRGB, .hdr Radiance RGBE, .exr), the bundled
sample environments, the generated `studio` (pipeline/environment/studio.py, the default), and synthetic HDR
panoramas for tests and the reference renderer.

Pixels are H x W x 3 float32 linear radiance, row 0 at the top, in the equirect convention of
`core.cubemap` (centre column looks toward +Z, top row straight up).
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.colour import srgb_to_linear
from core.cubemap import equirect_direction
from core.errors import AssetError, LimitExceeded, MalformedAsset, MissingFile, UnsupportedFormat
from pipeline.deadline import check, within
from pipeline.environment import scaled, studio, uniform
from pipeline.images import decode_image
from pipeline.limits import Limits

log = logging.getLogger(__name__)

DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "env"
DEFAULT_ENVIRONMENT = "studio"  # generated in code, pipeline/environment/studio.py
LDR_SUFFIXES = (".jpg", ".jpeg", ".png")
HDR_SUFFIXES = (".hdr", ".pic", ".exr")


@dataclass
class Panorama:
    name: str
    pixels: np.ndarray                      # H x W x 3 float32, linear
    files: list[Path] = field(default_factory=list)


def list_bundled() -> list[str]:
    """Names usable as `load_panorama(name)`: the generated `studio` first, then the panoramas
    shipped in pipeline/data/env."""
    return [studio.NAME] + sorted(p.stem for p in DATA_DIR.glob("*.jpg"))


def load_panorama(source: str | Path, limits: Limits | None = None) -> Panorama:
    """Read a panorama file, or a bundled one by bare name (`studio`, `footprint_court`, see
    `list_bundled`). Raises an `AssetError` subclass naming the file on bad input."""
    limits = limits or Limits.from_env()
    factor = scaled.parse(source)
    if factor is not None:  # a textured dome's intensity x exposure x colour
        inner = load_panorama(factor[1], limits)
        pixels = np.clip(inner.pixels * np.asarray(factor[0], np.float32), 0.0, uniform.MAX_RADIANCE)
        return Panorama(name=inner.name, pixels=pixels.astype(np.float32), files=inner.files)
    path = resolve_panorama(source)
    if path == studio.SOURCE:
        return Panorama(name=studio.NAME, pixels=studio.studio_panorama().copy(), files=[path])
    rgb = uniform.parse(source)
    if rgb is not None:
        return Panorama(name=str(source), pixels=uniform.panorama(rgb), files=[path])
    suffix = path.suffix.lower()
    if suffix not in LDR_SUFFIXES + HDR_SUFFIXES:
        raise UnsupportedFormat(path, f"not a panorama format ({', '.join(LDR_SUFFIXES + HDR_SUFFIXES)})")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise MissingFile(path, f"cannot read: {exc.strerror}") from None
    if size > limits.max_file_bytes:
        raise LimitExceeded(path, f"file is {size} bytes, over the limit of {limits.max_file_bytes}")
    if suffix == ".exr":
        pixels = _read_exr(path, limits)
    else:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise MissingFile(path, f"cannot read: {exc.strerror}") from None
        if suffix in LDR_SUFFIXES:
            pixels = srgb_to_linear(decode_image(data, str(path), limits)[..., :3])
        else:
            with within(limits.ingest_seconds, str(path)):  # the RLE decoder checks it per scanline
                pixels = read_rgbe(data, str(path), limits)
    if pixels.shape[0] < 2 or pixels.shape[1] < 4:
        raise MalformedAsset(path, f"panorama of {pixels.shape[1]}x{pixels.shape[0]} pixels is too small")
    if pixels.shape[1] != 2 * pixels.shape[0]:
        log.warning("%s: %dx%d is not a 2:1 equirectangular panorama; mapping it as one",
                    path, pixels.shape[1], pixels.shape[0])
    return Panorama(name=path.stem, pixels=_sanitize(pixels, path), files=[path])


def resolve_panorama(source: str | Path) -> Path:
    """The file a panorama source names: an existing path, else a bundled name's JPEG; the
    name `studio` resolves to the module that generates it (its hash keys the bake)."""
    factor = scaled.parse(source)
    if factor is not None:  # `scaled:R,G,B:PATH` (pipeline/environment/scaled.py): its file
        return resolve_panorama(factor[1])
    if source == studio.NAME:
        return studio.SOURCE
    if uniform.parse(source) is not None:  # `dark`, `uniform:R,G,B` (pipeline/environment/uniform.py)
        return uniform.SOURCE
    path = Path(source)
    if path.is_file():
        return path
    if isinstance(source, str) and re.fullmatch(r"[A-Za-z0-9_\-]+", source):
        bundled = DATA_DIR / f"{source}.jpg"
        if bundled.is_file():
            return bundled
        raise MissingFile(source, "no such file or bundled environment (bundled: "
                                  f"{', '.join(list_bundled())})")
    raise MissingFile(path, "no such file")


def _sanitize(pixels: np.ndarray, path: Path) -> np.ndarray:
    """HDR files may hold NaN, inf, negative or huge values: NaN and negatives become 0, the rest
    is clamped to the float16 maximum (65504) so that half-float caches and GL sums stay finite."""
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    bad = ~(np.abs(pixels - 32752.0) <= 32752.0)  # outside [0, 65504], NaN included
    if bad.any():
        log.warning("%s: %d NaN, negative or out-of-range values clamped", path, int(bad.sum()))
        pixels = np.clip(np.nan_to_num(pixels, nan=0.0, posinf=65504.0), 0.0, 65504.0)
    return pixels


# Radiance RGBE (.hdr) -------------------------------------------------------------------------

_RESOLUTION = re.compile(rb"([-+])([XY]) +(\d+) +([-+])([XY]) +(\d+)")


def read_rgbe(data: bytes, source: str, limits: Limits | None = None) -> np.ndarray:
    """Decode a Radiance RGBE file (flat or run-length encoded scanlines) to float32 linear.
    Only the run headers are walked in Python; pixels move in bulk slices."""
    limits = limits or Limits()
    if not data.startswith((b"#?RADIANCE", b"#?RGBE")):
        raise MalformedAsset(source, "not a Radiance HDR file (no #?RADIANCE signature)")
    end = data.find(b"\n\n")
    if end < 0:
        raise MalformedAsset(source, "HDR header does not end")
    header = data[:end].decode("latin-1")
    fmt = re.search(r"^FORMAT=(\S+)", header, re.M)
    if fmt and fmt.group(1) != "32-bit_rle_rgbe":
        raise UnsupportedFormat(source, f"HDR pixel format {fmt.group(1)} (only 32-bit_rle_rgbe)")
    line_end = data.find(b"\n", end + 2)
    match = _RESOLUTION.fullmatch(data[end + 2:line_end if line_end >= 0 else None].strip())
    if not match or match.group(2) == match.group(5):
        raise MalformedAsset(source, "HDR resolution line is missing or malformed")
    sign1, axis1, n1, sign2, _, n2 = match.groups()
    rows, cols = int(n1), int(n2)
    if rows == 0 or cols == 0:
        raise MalformedAsset(source, "HDR image has zero size")
    if rows * cols > limits.max_texture_pixels:
        raise LimitExceeded(source, f"HDR image is {cols}x{rows}, over the limit of "
                                    f"{limits.max_texture_pixels} pixels")
    rgbe = _decode_scanlines(memoryview(data)[line_end + 1:], rows, cols, source)
    rgbe = rgbe.reshape(rows, cols, 4)
    if sign1 == b"+":
        rgbe = rgbe[::-1]
    if sign2 == b"-":
        rgbe = rgbe[:, ::-1]
    if axis1 == b"X":  # scanlines are columns
        rgbe = rgbe.transpose(1, 0, 2)
    exponent = rgbe[..., 3].astype(np.int32)
    # Radiance's colr_color: (mantissa + 0.5) * 2^(e - 136), and e = 0 means black.
    scale = np.where(exponent > 0, np.ldexp(np.float32(1.0), exponent - 136), 0.0).astype(np.float32)
    return (rgbe[..., :3].astype(np.float32) + 0.5) * scale[..., None]


def _decode_scanlines(buf: memoryview, rows: int, cols: int, source: str) -> np.ndarray:
    out = bytearray(rows * cols * 4)
    pos = 0
    n = len(buf)
    planar = bytearray(cols * 4)
    for row in range(rows):
        check()
        if n - pos < 4:
            raise MalformedAsset(source, f"HDR data truncated at scanline {row}")
        head = bytes(buf[pos:pos + 4])
        if not (8 <= cols < 32768 and head[0] == 2 and head[1] == 2 and (head[2] << 8 | head[3]) == cols):
            if head[:3] == b"\x01\x01\x01":
                raise UnsupportedFormat(source, "old-style run-length HDR encoding")
            if n - pos < cols * 4:  # flat scanline
                raise MalformedAsset(source, f"HDR data truncated at scanline {row}")
            out[row * cols * 4:(row + 1) * cols * 4] = buf[pos:pos + cols * 4]
            pos += cols * 4
            continue
        pos += 4
        for channel in range(4):  # channels stored one after another, each run-length coded
            x = channel * cols
            stop = x + cols
            while x < stop:
                if pos >= n:
                    raise MalformedAsset(source, f"HDR data truncated at scanline {row}")
                count = buf[pos]
                if count > 128:
                    count -= 128
                    if x + count > stop or pos + 1 >= n:
                        raise MalformedAsset(source, f"HDR run overruns scanline {row}")
                    planar[x:x + count] = bytes((buf[pos + 1],)) * count
                    pos += 2
                else:
                    if count == 0 or x + count > stop or pos + 1 + count > n:
                        raise MalformedAsset(source, f"HDR run overruns scanline {row}")
                    planar[x:x + count] = buf[pos + 1:pos + 1 + count]
                    pos += 1 + count
                x += count
        line = np.frombuffer(planar, dtype=np.uint8).reshape(4, cols).T
        out[row * cols * 4:(row + 1) * cols * 4] = line.tobytes()
    return np.frombuffer(out, dtype=np.uint8)


def write_rgbe(path: str | Path, pixels: np.ndarray) -> None:
    """Write float RGB as a flat (uncompressed) Radiance HDR file."""
    pixels = np.maximum(np.asarray(pixels, dtype=np.float64), 0.0)
    peak = pixels.max(axis=-1)
    mantissa, exponent = np.frexp(peak)
    ok = peak > 1e-32
    scale = np.where(ok, mantissa * 256.0 / np.where(ok, peak, 1.0), 0.0)
    rgbe = np.zeros(pixels.shape[:2] + (4,), dtype=np.uint8)
    rgbe[..., :3] = np.clip(pixels * scale[..., None], 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(ok, exponent + 128, 0)
    h, w = pixels.shape[:2]
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode()
    Path(path).write_bytes(header + rgbe.tobytes())


# OpenEXR --------------------------------------------------------------------------------------

def _read_exr(path: Path, limits: Limits) -> np.ndarray:
    try:
        import OpenEXR  # only .exr panoramas need it
    except ImportError:
        raise UnsupportedFormat(path, "reading .exr needs the 'openexr' package") from None
    try:
        header = OpenEXR.File(str(path), header_only=True).header()
        (x0, y0), (x1, y1) = header["dataWindow"]
        w, h = int(x1 - x0 + 1), int(y1 - y0 + 1)
        if w <= 0 or h <= 0:
            raise MalformedAsset(path, f"EXR data window is {w}x{h}")
        if w * h > limits.max_texture_pixels:
            raise LimitExceeded(path, f"EXR image is {w}x{h}, over the limit of "
                                      f"{limits.max_texture_pixels} pixels")
        channels = OpenEXR.File(str(path), separate_channels=True).channels()
    except AssetError:
        raise
    except Exception as exc:  # the bindings raise RuntimeError/ValueError for broken files
        raise MalformedAsset(path, f"EXR does not decode: {exc}") from None
    names = {name.split(".")[-1].upper(): ch.pixels for name, ch in channels.items()}
    if all(c in names for c in "RGB"):
        planes = [names[c] for c in "RGB"]
    elif "Y" in names:
        planes = [names["Y"]] * 3
    else:
        raise UnsupportedFormat(path, f"EXR has no R, G, B or Y channels ({', '.join(channels)})")
    if any(p.shape != (h, w) for p in planes):
        raise UnsupportedFormat(path, "EXR channels are subsampled")
    return np.stack([p.astype(np.float32) for p in planes], axis=-1)


# Synthetic panoramas --------------------------------------------------------------------------

SYNTHETIC = ("white", "gradient", "sky_sun", "checker")
SUN_DIRECTION = np.array([0.5, 0.6, 0.6245]) / np.linalg.norm([0.5, 0.6, 0.6245])
SUN_RADIANCE = 200.0
SUN_RADIUS_DEG = 2.0


def synthetic_panorama(kind: str = "sky_sun", width: int = 512) -> np.ndarray:
    """A width x width/2 x 3 float32 linear panorama made in code (HDR values allowed):
    white (a furnace of radiance 1), gradient (smooth sky-to-ground colours), sky_sun
    (gradient plus a sun disc of radiance SUN_RADIANCE and SUN_RADIUS_DEG in SUN_DIRECTION),
    checker (a 16 x 8 checkerboard of 0.05 / 1 whose vertical edges include the cube's
    vertical edges: the worst case for per-face filtering)."""
    if kind not in SYNTHETIC:
        raise ValueError(f"unknown synthetic panorama {kind!r}; one of {SYNTHETIC}")
    h = width // 2
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    d = equirect_direction(uu, vv)
    if kind == "white":
        return np.ones((h, width, 3), np.float32)
    if kind == "checker":
        cell = (np.floor(uu * 16) + np.floor(vv * 8)) % 2
        return np.repeat((0.05 + 0.95 * cell)[..., None], 3, axis=-1).astype(np.float32)
    y = d[..., 1:2]
    sky = np.array([0.35, 0.55, 0.95]) * (0.6 + 0.8 * np.clip(y, 0, 1))
    ground = np.array([0.30, 0.22, 0.15]) * (0.6 - 0.3 * np.clip(-y, 0, 1))
    t = 0.5 + 0.5 * np.tanh(y * 4.0)  # smooth horizon
    pixels = t * sky + (1 - t) * ground + 0.15 * (d[..., 0:1] + 1) * np.array([0.6, 0.3, 0.0])
    if kind == "sky_sun":
        cos_angle = d @ SUN_DIRECTION
        pixels = pixels + SUN_RADIANCE * (cos_angle > np.cos(np.radians(SUN_RADIUS_DEG)))[..., None]
    return pixels.astype(np.float32)
