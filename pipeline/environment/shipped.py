"""The default `studio` environment's bake, shipped in pipeline/data like the BRDF LUT.

A cold process with an empty cache would otherwise spend a third of its first image
prefiltering a light that is the same for everyone (pipeline/environment/studio.py makes it in
code). `pipeline.bake` loads these arrays on a cache miss whose key is one shipped here, and
stores them in the cache as a bake would; any other key (another environment, face size or
method, or an edit of studio.py or of the filter's constants, which all change the key) bakes
as before.

Members of STUDIO_BAKES are named by the full cache key, so a stale file is never served: it
just stops matching, and tests/test_environment.py fails until `make studio-env`
(`python -m pipeline.environment.shipped`) rewrites it. Specular mips are stored as one grey
float16 channel (the studio is neutral: R = G = B in every texel), the irradiance cube as one
float32 channel; loading widens them back to 6 x S x S x 3 float32. Only the face sizes a render of up to 256 px picks
(`core.cubemap.default_face_size`, bounded below by the smoothest material) are shipped; 512
px faces would quadruple the file for larger renders, which bake theirs.
"""
from __future__ import annotations

import logging
import zipfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from core import irradiance
from core.cubemap import default_levels
from pipeline.cache import SourceFiles
from pipeline.environment import prefilter as environment
from pipeline.environment import scaled, studio, uniform
from pipeline.environment.panorama import resolve_panorama

log = logging.getLogger(__name__)

STUDIO_BAKES = Path(__file__).resolve().parents[1] / "data" / "studio_bakes.npz"
SHIPPED_FACE_SIZES = (32, 64, 128, 256)


def environment_options(source, face_size: int, prefilter: str) -> dict:
    """The options that key an environment bake besides its source file's content."""
    # The filter's own constants are part of the key: changing them must not serve old bakes.
    opts: dict = {"face_size": face_size, "prefilter": prefilter, "version": environment.PREFILTER_VERSION,
                  "levels": default_levels(face_size), "ggx_samples": environment.GGX_SAMPLES,
                  "lut": [environment.LUT_SIZE, environment.LUT_SAMPLES],
                  "irradiance": [irradiance.IRRADIANCE_FACE, irradiance.SOURCE_FACE]}
    if uniform.parse(source) is not None:  # one module makes every uniform one: the value keys it
        opts["uniform"] = list(uniform.parse(source))  # type: ignore[arg-type]
    if scaled.parse(source) is not None:  # a textured dome's factor: the file's content and it
        opts["scale"] = list(scaled.parse(source)[0])  # type: ignore[index]
    return opts


def environment_key(source, face_size: int, prefilter: str) -> tuple[SourceFiles, dict, str]:
    """(hashed source files, options, cache key) of an environment bake."""
    opts = environment_options(source, face_size, prefilter)
    source_files = SourceFiles.hash(resolve_panorama(source))
    return source_files, opts, source_files.key("environments", opts)


@lru_cache(maxsize=1)
def _members() -> frozenset[str]:
    try:
        with zipfile.ZipFile(STUDIO_BAKES) as z:
            return frozenset(n.removesuffix(".npy") for n in z.namelist())
    except (OSError, zipfile.BadZipFile):
        return frozenset()


def shipped_keys() -> list[str]:
    """The cache keys STUDIO_BAKES holds a bake for."""
    return sorted(n.removesuffix(".sh") for n in _members() if n.endswith(".sh"))


def load_shipped(key: str) -> environment.EnvironmentArrays | None:
    """The shipped bake for this cache key, or None when none is shipped under it."""
    if f"{key}.sh" not in _members():
        return None
    with np.load(STUDIO_BAKES) as z:
        levels = int(z[f"{key}.levels"])
        specular = [np.repeat(z[f"{key}.specular{m}"].astype(np.float32)[..., None], 3, axis=-1)
                    for m in range(levels)]
        sh = z[f"{key}.sh"].astype(np.float32)
        irradiance = np.repeat(z[f"{key}.irradiance"].astype(np.float32)[..., None], 3, axis=-1)
    log.info("environment %s: loaded the shipped studio bake", key[:16])
    return environment.EnvironmentArrays(specular=specular, irradiance_sh=sh, brdf_lut=environment.brdf_lut(),
                                         irradiance=irradiance, method="ggx")


def bake_studio(face_size: int) -> environment.EnvironmentArrays:
    """The studio prefiltered now, as a cache miss without the shipped file would."""
    return environment.prefilter(studio.studio_panorama(), face_size=face_size, method="ggx")


def write_studio_bakes(path: Path = STUDIO_BAKES) -> list[str]:
    """Prefilter the studio at every shipped face size and write them under their keys."""
    members: dict[str, np.ndarray] = {}
    keys = []
    for face in SHIPPED_FACE_SIZES:
        _, _, key = environment_key(studio.NAME, face, "ggx")
        env = bake_studio(face)
        for m, mip in enumerate(env.specular):
            if not np.array_equal(mip[..., 0], mip[..., 1]) or not np.array_equal(mip[..., 0], mip[..., 2]):
                raise ValueError(f"studio mip {m} at {face} px is not grey: the one-channel file cannot hold it")
            members[f"{key}.specular{m}"] = mip[..., 0].astype(np.float16)
        members[f"{key}.levels"] = np.array(len(env.specular))
        members[f"{key}.face_size"] = np.array(face)
        members[f"{key}.sh"] = np.asarray(env.irradiance_sh, np.float32)
        if not (np.array_equal(env.irradiance[..., 0], env.irradiance[..., 1])
                and np.array_equal(env.irradiance[..., 0], env.irradiance[..., 2])):
            raise ValueError(f"studio irradiance at {face} px is not grey: the one-channel file cannot hold it")
        members[f"{key}.irradiance"] = env.irradiance[..., 0].astype(np.float32)
        keys.append(key)
    np.savez_compressed(path, **members)  # type: ignore[arg-type]
    _members.cache_clear()
    return keys


if __name__ == "__main__":  # `make studio-env`: (re)write the shipped studio bakes for the current constants
    for k in write_studio_bakes():
        print(f"{STUDIO_BAKES.name}: {k}")
    print(f"wrote {STUDIO_BAKES} ({STUDIO_BAKES.stat().st_size} bytes)")
