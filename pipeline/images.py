"""Decoding texture images from untrusted bytes, with the pixel count checked first."""
from __future__ import annotations

import io
import logging
import warnings

import numpy as np
from PIL import Image

from .errors import LimitExceeded, MalformedAsset
from .limits import Limits

log = logging.getLogger(__name__)

FORMATS = ("PNG", "JPEG", "WEBP")


def decode_image(data: bytes, source: str, limits: Limits) -> np.ndarray:
    """Decode PNG/JPEG/WebP bytes into an H x W x 4 uint8 array, row 0 at the top.

    The size is read from the header (Pillow opens lazily) and checked against
    `limits.max_texture_pixels` before any pixel is decoded, so a decompression bomb costs
    nothing. Raises MalformedAsset (not an image, truncated, unsupported format) or
    LimitExceeded, naming `source`.
    """
    try:
        with warnings.catch_warnings():
            # Pillow's own bomb guard: a warning past its limit, an error past twice it.
            # Ours is checked below; make Pillow's a hard error at the same size.
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            Image.MAX_IMAGE_PIXELS = max(Image.MAX_IMAGE_PIXELS or 0, limits.max_texture_pixels)
            im = Image.open(io.BytesIO(data), formats=FORMATS)
            w, h = im.size
            if w <= 0 or h <= 0:
                raise MalformedAsset(source, f"image has size {w}x{h}")
            if w * h > limits.max_texture_pixels:
                raise LimitExceeded(source, f"image is {w}x{h} = {w * h} pixels, over the limit "
                                            f"of {limits.max_texture_pixels}")
            im = im.convert("RGBA")  # decodes; palette/grey/16-bit all become RGBA8
            arr = np.asarray(im, dtype=np.uint8)
    except (LimitExceeded, MalformedAsset):
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise LimitExceeded(source, f"image too large: {exc}") from None
    except Image.UnidentifiedImageError:
        raise MalformedAsset(source, "not a PNG, JPEG or WebP image") from None
    except (OSError, SyntaxError, ValueError, EOFError) as exc:
        raise MalformedAsset(source, f"image does not decode: {exc}") from None
    if arr.ndim != 3 or arr.shape[2] != 4:
        raise MalformedAsset(source, f"image decoded to unexpected shape {arr.shape}")
    return np.ascontiguousarray(arr)
