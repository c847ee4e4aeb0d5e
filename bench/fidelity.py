"""`asset-preview bench fidelity`: our images beside a path tracer's, per Khronos sample model.

Each model under ../shared/assets/gltf-samples/ (else tests/assets/gltf-samples; its .glb, else its .gltf) is rendered from a
fixed three-quarter camera (yaw 35, pitch 25, fov 40, auto-framed on the world bounds:
renderer.view.camera) under one panorama, by us (`--method auto`, the default thumbnail), by our ray
tracer (`--method raytrace`) and, as the reference, by Blender Cycles (Debian's `blender`
package, headless, through Blender's own glTF importer; bench/blender_cycles.py) with the same
camera and panorama. All three are linear, over a transparent film (RGB premultiplied, alpha =
coverage), tone-mapped alike (ACES as the Sample Viewer, exposure 0, sRGB) and compared with
LDR FLIP (flip-evaluator) over the pixels either image covers; the table gives mean FLIP per
model and the mean over the scored models.

The panorama is handed to Blender turned into its equirect convention (Blender's u starts a
quarter turn off ours); the `calibration` row, a mirror
sphere (bench.scenes.mirror_sphere), checks that mapping and the camera before any model is
scored. Cycles' Principled BSDFs are switched to multiscatter GGX, as reference viewers do.
Where the importer of the installed Blender lacks an extension a model uses, that model's
row says which and is not scored against Cycles (ours vs raytrace is still reported). Without
Blender the bench says so and reports ours vs raytrace only.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.assets import CORPUS

ROOT = Path(__file__).resolve().parents[1]
MODELS = CORPUS / "gltf-samples"
VIEW = {"yaw": 35.0, "pitch": 25.0, "fov": 40.0}
# glTF (+Y up) -> Blender (+Z up), as Blender's glTF importer converts: (x, y, z) -> (x, -z, y).
TO_BLENDER = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--samples", type=Path, default=MODELS, help="folder of Khronos sample model folders")
    p.add_argument("--models", default=None, help="comma-separated model folder names (default: all)")
    p.add_argument("--size", type=int, default=128, help="image size (pixels, square)")
    p.add_argument("--spp", type=int, default=64, help="Cycles samples per pixel")
    p.add_argument("--env", default="footprint_court", help="bundled panorama")
    p.add_argument("--blender", default=shutil.which("blender"), help="Blender executable")
    p.add_argument("--blender-seconds", type=float, default=600, help="per-model time limit")
    p.add_argument("--out", default="bench-results", help="folder for fidelity.csv and images")
    p.add_argument("--cache", default=None, help="bake cache (default: a temporary folder)")
    p.add_argument("--quick", action="store_true", help="three models at 64 px, 16 spp")


def model_files(names: list[str] | None = None, samples: Path = MODELS) -> list[tuple[str, Path | None]]:
    """(model, its .glb or .gltf or None) for each folder under `samples`."""
    out = []
    for folder in sorted(p for p in samples.iterdir() if p.is_dir()):
        if names and folder.name not in names:
            continue
        found = None
        for sub, pattern in (("glTF-Binary", "*.glb"), ("glTF", "*.gltf")):
            hits = sorted((folder / sub).glob(pattern)) if (folder / sub).is_dir() else []
            if hits:
                found = hits[0]
                break
        out.append((folder.name, found))
    return out


def extensions_used(path: Path) -> list[str]:
    """The glTF's extensionsUsed (JSON chunk of a .glb, or the .gltf itself)."""
    data = path.read_bytes()
    if data[:4] == b"glTF":
        length = int.from_bytes(data[12:16], "little")
        doc = json.loads(data[20:20 + length])
    else:
        doc = json.loads(data)
    return sorted(doc.get("extensionsUsed", []))


def blender_panorama(pano: np.ndarray) -> np.ndarray:
    """Our equirect (u = 0.5 + atan2(-x, z) / 2pi, glTF axes) re-indexed for Blender's
    environment texture (u_b = 0.5 - atan2(y_b, x_b) / 2pi in Blender axes, y_b = -z): for every
    direction u_b = u + 1/4, so the panorama turns a quarter of its width (column j holds our
    column j - W/4); rows agree (v from the top row, straight up)."""
    return np.ascontiguousarray(np.roll(pano, int(round(pano.shape[1] / 4)), axis=1))


def blender_camera(camera) -> list[list[float]]:
    """Camera-to-world in Blender axes: columns right, up, backward (-forward), position."""
    r, u, f = camera.basis()
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = TO_BLENDER @ r, TO_BLENDER @ u, TO_BLENDER @ -f
    m[:3, 3] = TO_BLENDER @ camera.position
    return m.tolist()


def read_exr(path: str) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGBA" in ch:
            return np.asarray(ch["RGBA"].pixels, np.float32)
        return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGBA"], axis=-1)


def run_blender(blender: str, job: dict, workdir: Path, seconds: float) -> tuple[np.ndarray | None, str]:
    """Cycles' linear RGBA for `job`, or None and why."""
    job_path = workdir / "job.json"
    job_path.write_text(json.dumps(job))
    cmd = [blender, "-b", "--factory-startup", "--python-exit-code", "3",
           "-P", str(ROOT / "bench" / "blender_cycles.py"), "--", str(job_path)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=seconds)
    except subprocess.TimeoutExpired:
        return None, f"Blender took over {seconds:.0f} s"
    if proc.returncode != 0 or not os.path.isfile(job["out"]):
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        return None, "Blender failed: " + " | ".join(tail)
    return read_exr(job["out"]), ""


def display(linear: np.ndarray) -> np.ndarray:
    """ACES tone map + sRGB of premultiplied linear RGB over black (renderer.frame)."""
    from renderer.frame import srgb_encode, tonemap

    return srgb_encode(tonemap(np.clip(linear[..., :3], 0, None), "aces", 0.0)).astype(np.float32)


def flip_ldr(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean LDR FLIP of tone-mapped `image` against `reference` where either covers a pixel."""
    import flip_evaluator

    mask = (image[..., 3] > 0) | (reference[..., 3] > 0)
    if not mask.any():
        return 0.0
    emap, _, _ = flip_evaluator.evaluate(np.ascontiguousarray(display(reference)),
                                         np.ascontiguousarray(display(image)), "LDR",
                                         inputsRGB=True, applyMagma=False, computeMeanError=False)
    return float(np.asarray(emap).reshape(mask.shape)[mask].mean())


def _save_png(path: Path, linear: np.ndarray) -> None:
    from PIL import Image

    rgb = np.round(display(linear) * 255).clip(0, 255).astype(np.uint8)
    a = np.round(np.clip(linear[..., 3], 0, 1) * 255).astype(np.uint8)
    Image.fromarray(np.dstack([rgb, a]), "RGBA").save(path)


def run(args: argparse.Namespace) -> int:
    from bench import scenes
    from core.errors import AssetError
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from pipeline.environment.panorama import load_panorama
    from renderer.frame import write_exr
    from renderer.raster.render import render
    from renderer.view.framing import request_camera

    if args.quick:
        args.size, args.spp = 64, 16
        args.models = args.models or "Box,Duck,NegativeScaleTest"
    names = args.models.split(",") if args.models else None
    out = Path(args.out)
    (out / "fidelity").mkdir(parents=True, exist_ok=True)
    cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="bench-fidelity-"))
    work = Path(tempfile.mkdtemp(prefix="bench-fidelity-blender-"))
    env = bake_environment(args.env, cache, face_size=256)
    options = RenderOptions(width=args.size, height=args.size, background="transparent",
                            tonemap="aces", yaw=VIEW["yaw"], pitch=VIEW["pitch"], fov=VIEW["fov"])

    blender, supported, note = args.blender, set(), ""
    if not blender:
        note = ("Blender is not installed (Debian: apt-get install -y blender, about 80 MB of "
                "packages): no Cycles reference, ours vs raytrace only")
    else:
        pano_path = work / "panorama.exr"
        pano = np.asarray(load_panorama(args.env).pixels, np.float32)[..., :3]
        write_exr(str(pano_path), np.dstack([blender_panorama(pano), np.ones(pano.shape[:2], np.float32)]))
        probe = work / "extensions.json"
        try:
            proc = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "3",
                                   "-P", str(ROOT / "bench" / "blender_cycles.py"), "--",
                                   str(_write(work / "probe.json", {"query": "extensions", "out": str(probe)}))],
                                  capture_output=True, text=True, timeout=300)
            if not probe.is_file():
                raise ValueError((proc.stderr or proc.stdout).strip().splitlines()[-1:] or "no answer")
            info = json.loads(probe.read_text())
            supported = set(info["extensions"])
            note = f"Blender {info['blender']} Cycles, {args.spp} spp, importer handles {len(supported)} extensions"
        except (OSError, subprocess.SubprocessError, ValueError, KeyError) as exc:
            blender, note = None, f"Blender at {args.blender} did not answer ({exc}): ours vs raytrace only"
    print(f"# bench fidelity: {args.size} px, env {args.env}, yaw {VIEW['yaw']:g} pitch {VIEW['pitch']:g}; {note}")

    rows = []
    jobs: list[tuple[str, Path | None]] = [
        ("calibration", scenes.write_glb(scenes.scene("mirror_sphere"), work / "mirror_sphere.glb"))]
    jobs += model_files(names, args.samples)
    for name, path in jobs:
        row = {"model": name, "ours_flip": "", "raytrace_flip": "", "ours_vs_raytrace": "",
               "ours_ms": "", "raytrace_ms": "", "cycles_s": "", "note": ""}
        rows.append(row)
        if path is None:
            row["note"] = "no .glb or .gltf in the folder"
            _print(row)
            continue
        try:
            asset = bake_asset(path, cache)
        except AssetError as exc:
            row["note"] = f"not ingested: {exc}"
            _print(row)
            continue
        t = time.perf_counter()
        ours = render(asset, env, options).linear
        row["ours_ms"] = f"{(time.perf_counter() - t) * 1e3:.0f}"
        t = time.perf_counter()
        traced = render(asset, env, options.replace(method="raytrace")).linear
        row["raytrace_ms"] = f"{(time.perf_counter() - t) * 1e3:.0f}"
        row["ours_vs_raytrace"] = f"{flip_ldr(ours, traced):.3f}"
        _save_png(out / "fidelity" / f"{name}_ours.png", ours)
        _save_png(out / "fidelity" / f"{name}_raytrace.png", traced)
        missing = sorted(set(extensions_used(path)) - supported) if blender else []
        if not blender:
            row["note"] = "no Cycles reference"
        elif missing:
            row["note"] = "Blender's importer lacks " + ", ".join(missing) + ": not scored"
        else:
            camera = request_camera(asset, options)
            job = {"gltf": str(path), "panorama": str(pano_path), "out": str(work / f"{name}.exr"),
                   "size": args.size, "spp": args.spp, "camera_matrix": blender_camera(camera),
                   "fov": camera.fov, "clip": [camera.near * 0.5, camera.far * 2]}
            t = time.perf_counter()
            ref, why = run_blender(blender, job, work, args.blender_seconds)
            row["cycles_s"] = f"{time.perf_counter() - t:.1f}"
            if ref is None:
                row["note"] = why
            else:
                row["ours_flip"] = f"{flip_ldr(ours, ref):.3f}"
                row["raytrace_flip"] = f"{flip_ldr(traced, ref):.3f}"
                _save_png(out / "fidelity" / f"{name}_cycles.png", ref)
        _print(row)
    scored = [r for r in rows if r["ours_flip"] and r["model"] != "calibration"]
    if scored:
        mean = {k: np.mean([float(r[k]) for r in scored]) for k in ("ours_flip", "raytrace_flip")}
        print(f"mean over {len(scored)} scored models: ours {mean['ours_flip']:.3f}, "
              f"raytrace {mean['raytrace_flip']:.3f} (FLIP against Cycles)")
    with open(out / "fidelity.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {out / 'fidelity.csv'} and images in {out / 'fidelity'}")
    return 0


def _write(path: Path, obj) -> Path:
    path.write_text(json.dumps(obj))
    return path


def _print(row: dict) -> None:
    print(f"{row['model']:<24} ours {row['ours_flip'] or '-':>6}  raytrace {row['raytrace_flip'] or '-':>6}"
          f"  ours~raytrace {row['ours_vs_raytrace'] or '-':>6}  ({row['ours_ms'] or '-'} ms /"
          f" {row['raytrace_ms'] or '-'} ms / Cycles {row['cycles_s'] or '-'} s)  {row['note']}",
          flush=True)
