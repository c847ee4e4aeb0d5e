"""The bake's occlusion pass time (manifest timings occlusion_s) on a few sample models, three
bakes each (the first includes numba's compile): `PYTHONPATH=. python -m bench.occlusion_time
--samples ../shared/assets/gltf-samples Duck CesiumMan`."""
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
    from pipeline.bake import build_baked
    from pipeline.ingest import load_scene
    for name in args.models:
        scene = load_scene(args.samples / name / "glTF-Binary" / f"{name}.glb")
        times = [build_baked(scene).manifest["timings"]["occlusion_s"] for _ in range(args.runs)]
        print(f"{name}: occlusion_s {[round(t, 3) for t in times]}, median {statistics.median(times):.3f}")


if __name__ == "__main__":
    main()
