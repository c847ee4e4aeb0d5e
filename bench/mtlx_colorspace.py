"""Load cost of honouring MaterialX image colorspaces: load_scene of usd-wg's
TextureCoordinateTestMaterialX plus decoding the textures its materials read (the lin_rec709
image's re-encoded copy on this branch). Run from a checkout with PYTHONPATH set to it:
`PYTHONPATH=. python -m bench.mtlx_colorspace`; prints the median of 7 and the warnings."""
import statistics
import sys
import time

from pipeline.ingest import load_scene

PATH = "/work/shared/assets/usd/TextureCoordinateTest/TextureCoordinateTestMaterialX.usda"


def main(path: str = PATH) -> None:
    times = []
    for _ in range(7):
        t = time.perf_counter()
        scene = load_scene(path)
        for m in scene.materials:  # materialise what the materials read
            if m.base_color_texture:
                _ = scene.textures[m.base_color_texture.texture].image
        times.append((time.perf_counter() - t) * 1e3)
    print(f"median {statistics.median(times):.1f} ms over 7, warnings {scene.warnings}")


if __name__ == "__main__":
    main(*sys.argv[1:])
