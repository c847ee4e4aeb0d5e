"""The occlusion refinement's cost (pipeline.occlusion: triangles split where the visibility
varies) on sample models: per model the bake's vertices, triangles, mesh bytes and occlusion
time with the refinement off (a vertex budget of 0: the bake as before) and on, medians of
`--runs` bakes: `PYTHONPATH=. python -m bench.occlusion_refine --samples
../shared/assets/gltf-samples Duck CesiumMan`."""
from __future__ import annotations

import argparse
import statistics
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=Path, required=True)
    ap.add_argument("models", nargs="+")
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args(argv)
    from pipeline import occlusion
    from pipeline.bake import build_baked
    from pipeline.ingest import load_scene
    budget = occlusion.REFINE_MAX_VERTICES
    print("| model | vertices off / on | triangles off / on | mesh MB off / on | occlusion s off / on |")
    print("|---|---|---|---|---|")
    for name in args.models:
        folder = args.samples / name
        path = next(p for sub in ("glTF-Binary", "glTF") for p in sorted((folder / sub).glob("*.gl*")))
        scene = load_scene(path)
        row = {}
        for label, vertices in (("off", 0), ("on", budget)):
            occlusion.REFINE_MAX_VERTICES = vertices
            build_baked(scene)  # numba's compile, warm caches
            bakes = [build_baked(scene) for _ in range(args.runs)]
            stats = bakes[0].manifest["stats"]
            row[label] = (stats["vertices"], stats["triangles"],
                          sum(m.nbytes() for m in bakes[0].meshes) / 1e6,
                          statistics.median(b.manifest["timings"]["occlusion_s"] for b in bakes))
        occlusion.REFINE_MAX_VERTICES = budget
        off, on = row["off"], row["on"]
        print(f"| {name} | {off[0]} / {on[0]} | {off[1]} / {on[1]} | {off[2]:.3f} / {on[2]:.3f} "
              f"| {off[3]:.2f} / {on[3]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
