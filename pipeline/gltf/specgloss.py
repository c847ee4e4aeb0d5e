"""KHR_materials_pbrSpecularGlossiness converted to metallic-roughness at ingest.

The conversion is Khronos's (the extension's "convert-between-workflows" example): metallic is
solved from the perceived brightness of diffuse and specular, base colour blends the colour
implied by each, roughness = 1 - glossiness. With textures it runs per pixel, lazily (on the
first use of the pixels, as DeferredTexture does), into a new base-colour texture (sRGB, alpha
= opacity) and a new metallic-roughness texture (G roughness, B metallic).
"""
from __future__ import annotations

import numpy as np

from core.colour import srgb_encode, srgb_to_linear
from core.scene import Sampler, Texture

DIELECTRIC = 0.04
EPS = 1e-6


def _brightness(c: np.ndarray) -> np.ndarray:
    return np.sqrt(0.299 * c[..., 0] ** 2 + 0.587 * c[..., 1] ** 2 + 0.114 * c[..., 2] ** 2)


def convert(diffuse: np.ndarray, specular: np.ndarray, glossiness: np.ndarray):
    """Linear diffuse RGBA (..., 4), specular RGB (..., 3), glossiness (...) ->
    (base colour RGBA (..., 4), metallic (...), roughness (...)), all linear."""
    d, s = diffuse[..., :3], specular
    one_minus = 1.0 - s.max(axis=-1)
    bd, bs = _brightness(d), _brightness(s)
    b = bd * one_minus / (1 - DIELECTRIC) + bs - 2 * DIELECTRIC
    c = DIELECTRIC - bs
    with np.errstate(invalid="ignore"):
        root = (-b + np.sqrt(np.maximum(b * b - 4 * DIELECTRIC * c, 0.0))) / (2 * DIELECTRIC)
    metallic = np.where(bs < DIELECTRIC, 0.0, np.clip(root, 0.0, 1.0))
    m = metallic[..., None]
    from_diffuse = d * (one_minus / (1 - DIELECTRIC))[..., None] / np.maximum(1 - m, EPS)
    from_specular = (s - DIELECTRIC * (1 - m)) / np.maximum(m, EPS)
    base = np.clip(from_diffuse + (from_specular - from_diffuse) * m * m, 0.0, 1.0)
    rgba = np.concatenate([base, diffuse[..., 3:4]], axis=-1)
    return rgba, metallic, np.clip(1.0 - glossiness, 0.0, 1.0)


def convert_factors(diffuse, specular, glossiness) -> tuple[tuple, float, float]:
    rgba, metallic, roughness = convert(np.asarray(diffuse, np.float64),
                                        np.asarray(specular, np.float64), np.float64(glossiness))
    return tuple(float(v) for v in rgba), float(metallic), float(roughness)


class _Conversion:
    """The per-pixel conversion of one material, run once for both textures it makes."""

    def __init__(self, diffuse_tex: Texture | None, specgloss_tex: Texture | None,
                 diffuse_factor, specular_factor, glossiness_factor):
        self.sources = (diffuse_tex, specgloss_tex)
        self.factors = (np.asarray(diffuse_factor, np.float32),
                        np.asarray(specular_factor, np.float32), np.float32(glossiness_factor))
        self.result: tuple[np.ndarray, np.ndarray] | None = None

    def images(self) -> tuple[np.ndarray, np.ndarray]:
        if self.result is None:
            dt, st = self.sources
            fd, fs, fg = self.factors
            first = dt or st
            assert first is not None  # conversion_textures is only called with a texture
            shape = first.image.shape[:2]
            diffuse = np.broadcast_to(fd, (*shape, 4)).astype(np.float32)
            if dt is not None:
                img = dt.image
                diffuse = diffuse * np.concatenate(
                    [srgb_to_linear(img[..., :3]), img[..., 3:4] / np.float32(255)], axis=-1)
            specular = np.broadcast_to(fs, (*shape, 3)).astype(np.float32)
            gloss = np.full(shape, fg, np.float32)
            if st is not None:
                img = _resized(st.image, shape)
                specular = specular * srgb_to_linear(img[..., :3])
                gloss = gloss * (img[..., 3] / np.float32(255))
            rgba, metallic, roughness = convert(diffuse, specular, gloss)
            base = np.empty((*shape, 4), np.uint8)
            base[..., :3] = np.clip(srgb_encode(rgba[..., :3].astype(np.float32)) * 255 + 0.5, 0, 255)
            base[..., 3] = np.clip(rgba[..., 3] * 255 + 0.5, 0, 255)
            mr = np.zeros((*shape, 4), np.uint8)
            mr[..., 1] = np.clip(roughness * 255 + 0.5, 0, 255)
            mr[..., 2] = np.clip(metallic * 255 + 0.5, 0, 255)
            mr[..., 3] = 255
            self.result = (base, mr)
            self.sources = (None, None)
        return self.result


def _resized(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour resample of `img` to `shape` (the two maps may differ in size)."""
    if img.shape[:2] == shape:
        return img
    rows = (np.arange(shape[0]) * img.shape[0] // shape[0])
    cols = (np.arange(shape[1]) * img.shape[1] // shape[1])
    return img[rows][:, cols]


class ConvertedTexture(Texture):
    """One output (0: base colour, 1: metallic-roughness) of a lazy per-pixel conversion."""
    _image: np.ndarray | None

    def __init__(self, name: str, conversion: _Conversion, which: int, sampler: Sampler,
                 source: str):
        self._conversion, self._which = conversion, which
        super().__init__(name=name, image=None, sampler=sampler, source=source)  # type: ignore[arg-type]  # converted on first use

    @property
    def image(self) -> np.ndarray:
        if self._image is None:
            self._image = self._conversion.images()[self._which]
        return self._image

    @image.setter
    def image(self, value) -> None:
        self._image = value


def conversion_textures(diffuse_tex, specgloss_tex, diffuse_factor, specular_factor,
                        glossiness_factor) -> tuple[ConvertedTexture, ConvertedTexture]:
    """The base-colour and metallic-roughness textures converted from the two source
    textures (either may be None, then its factor alone counts)."""
    conv = _Conversion(diffuse_tex, specgloss_tex, diffuse_factor, specular_factor,
                       glossiness_factor)
    first = diffuse_tex or specgloss_tex
    label = f"{first.source} (specular-glossiness converted)"
    return (ConvertedTexture(f"{first.name}:baseColor", conv, 0, first.sampler, label),
            ConvertedTexture(f"{first.name}:metallicRoughness", conv, 1, first.sampler, label))
