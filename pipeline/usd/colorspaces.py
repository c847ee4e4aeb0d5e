"""MaterialX's standard colour spaces, converted to the working space lin_rec709.

The MaterialX specification names these spaces (section "Color Spaces and Color Management
Systems"); its default colour management system implements each as a transfer function then
a 3x3 gamut matrix (libraries/cmlib). The matrices here are derived from each space's primaries
and white point, with a Bradford adaptation to D65 where the white differs (AP1's ACES white),
and agree with cmlib's constants within 2e-5 (tests/test_materialx_colour.py reads them from the
installed library). The transfers are cmlib's: the piecewise sRGB curve for the srgb_* spaces,
plain powers (negative values clamped to 0) for the gamma spaces, rec709_display as a 2.4
power and adobergb as 563/256.

A space is (transfer, gamut): texels and colour values are decoded by the transfer, then
mapped from the gamut's primaries to Rec.709's.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from core.colour import srgb_decode, srgb_to_linear

Space = tuple[str, str]  # (transfer, gamut)

LIN_REC709: Space = ("linear", "rec709")
SRGB_TEXTURE: Space = ("srgb", "rec709")

D65 = (0.3127, 0.3290)
ACES_WHITE = (0.32168, 0.33767)
# (red, green, blue) xy chromaticities and the white point of each gamut
GAMUTS = {
    "rec709": (((0.64, 0.33), (0.30, 0.60), (0.15, 0.06)), D65),
    "ap1": (((0.713, 0.293), (0.165, 0.830), (0.128, 0.044)), ACES_WHITE),
    "displayp3": (((0.680, 0.320), (0.265, 0.690), (0.150, 0.060)), D65),
    "adobergb": (((0.64, 0.33), (0.21, 0.71), (0.15, 0.06)), D65),
    "rec2020": (((0.708, 0.292), (0.170, 0.797), (0.131, 0.046)), D65),
    "ap0": (((0.7347, 0.2653), (0.0, 1.0), (0.0001, -0.077)), ACES_WHITE),
}
POWERS = {"g18": 1.8, "g22": 2.2, "g24": 2.4, "adobe": 563.0 / 256.0}

SPACES: dict[str, Space] = {
    "srgb_texture": SRGB_TEXTURE,
    "lin_rec709": LIN_REC709,
    "lin_srgb": LIN_REC709,  # the spec's alias
    "g22_rec709": ("g22", "rec709"),
    "g18_rec709": ("g18", "rec709"),
    "rec709_display": ("g24", "rec709"),
    "acescg": ("linear", "ap1"),
    "lin_ap1": ("linear", "ap1"),
    "g22_ap1": ("g22", "ap1"),
    "g18_ap1": ("g18", "ap1"),
    "srgb_displayp3": ("srgb", "displayp3"),
    "lin_displayp3": ("linear", "displayp3"),
    "adobergb": ("adobe", "adobergb"),
    "lin_adobergb": ("linear", "adobergb"),
    # MaterialX 1.37's names, still met in older documents
    "gamma18": ("g18", "rec709"),
    "gamma22": ("g22", "rec709"),
    "gamma24": ("g24", "rec709"),
    # USD's own names (Gf.ColorSpaceNames, nanocolor's), which colorSpace metadata may carry
    "lin_rec709_scene": LIN_REC709,
    "srgb_rec709_scene": SRGB_TEXTURE,
    "g24_rec709_scene": ("g24", "rec709"),
    "g22_rec709_scene": ("g22", "rec709"),
    "g18_rec709_scene": ("g18", "rec709"),
    "lin_ap1_scene": ("linear", "ap1"),
    "srgb_ap1_scene": ("srgb", "ap1"),
    "g22_ap1_scene": ("g22", "ap1"),
    "lin_ap0_scene": ("linear", "ap0"),
    "lin_p3d65_scene": ("linear", "displayp3"),
    "srgb_p3d65_scene": ("srgb", "displayp3"),
    "lin_adobergb_scene": ("linear", "adobergb"),
    "g22_adobergb_scene": ("g22", "adobergb"),
    "lin_rec2020_scene": ("linear", "rec2020"),
    # values that are not colours: read as they are
    "raw": LIN_REC709,
    "data": LIN_REC709,
    "identity": LIN_REC709,
    "none": LIN_REC709,
}

BRADFORD = np.array([[0.8951, 0.2664, -0.1614],
                     [-0.7502, 1.7135, 0.0367],
                     [0.0389, -0.0685, 1.0296]])


def lookup(name: str) -> Space | None:
    """The space a MaterialX colorspace name declares, or None when it is not a standard one."""
    return SPACES.get(name.strip().lower())


def _xyz(xy) -> np.ndarray:
    x, y = xy
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


@lru_cache(maxsize=None)
def rgb_to_xyz(gamut: str) -> np.ndarray:
    """The gamut's RGB -> CIE XYZ matrix (columns: the primaries scaled so that RGB 1 is the
    white point at Y = 1)."""
    primaries, white = GAMUTS[gamut]
    p = np.stack([_xyz(c) for c in primaries], axis=1)
    return p * np.linalg.solve(p, _xyz(white))


@lru_cache(maxsize=None)
def to_rec709(gamut: str) -> np.ndarray:
    """3x3 matrix (column vectors) taking linear RGB in `gamut` to linear Rec.709, the white
    carried to D65 by a Bradford adaptation."""
    m = rgb_to_xyz(gamut)
    _, white = GAMUTS[gamut]
    if white != D65:
        src, dst = BRADFORD @ _xyz(white), BRADFORD @ _xyz(D65)
        m = np.linalg.inv(BRADFORD) @ np.diag(dst / src) @ BRADFORD @ m
    return np.linalg.solve(rgb_to_xyz("rec709"), m)


def decode(values: np.ndarray, transfer: str) -> np.ndarray:
    """Encoded values -> linear, by the named transfer (float64)."""
    v = np.asarray(values, np.float64)
    if transfer == "linear":
        return v.copy()
    if transfer == "srgb":
        return srgb_decode(v)
    return np.maximum(v, 0.0) ** POWERS[transfer]


def to_working(rgb: np.ndarray, space: Space) -> np.ndarray:
    """Colour values (..., 3) in `space` -> linear Rec.709 (unclipped, as MaterialX keeps them)."""
    transfer, gamut = space
    lin = decode(rgb, transfer)
    if gamut == "rec709":
        return lin
    return lin @ to_rec709(gamut).T


def bytes_to_working(rgb8: np.ndarray, space: Space) -> np.ndarray:
    """8-bit texels (..., 3) in `space` -> linear Rec.709 floats, through a 256-entry table
    (the sRGB one is core.colour's, so that plain sRGB recodes are the ones made before)."""
    transfer, gamut = space
    if transfer == "srgb":
        table = srgb_to_linear(np.arange(256, dtype=np.uint8)).astype(np.float64)
    else:
        table = decode(np.arange(256) / 255.0, transfer)
    lin = table[rgb8]
    if gamut == "rec709":
        return lin
    return lin @ to_rec709(gamut).T
