"""`asset-preview bench fidelity`: our images beside a path tracer's, per Khronos sample model.

Each model under ../shared/assets/gltf-samples/ (else tests/assets/gltf-samples; its .glb, else its .gltf) is rendered from a
fixed three-quarter camera (yaw 35, pitch 25, fov 40, auto-framed on the world bounds:
renderer.view.camera) under one panorama, by each of our methods under test (`--method auto,raytrace`
by default: the default thumbnail and the ray tracer, `--integrator tree|path` for the latter)
and, as the reference, by Blender Cycles through Blender's own glTF importer
(bench/blender_cycles.py) with the same camera and panorama. Cycles comes from the bpy wheel's
interpreter when ASSET_PREVIEW_BLENDER_PYTHON (or `--blender-python`) names one (a current
Blender, run in a subprocess of its own), else from Debian's `blender` package; the first
line says which ran. A reference render is kept beside the images with the job that made it
and reused while the job (model file, camera, panorama, samples, Blender) is the same. All three are linear, over a transparent film (RGB premultiplied, alpha =
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
import hashlib
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
BLENDER_PYTHON_ENV = "ASSET_PREVIEW_BLENDER_PYTHON"
WORKER = ROOT / "bench" / "blender_cycles.py"
METHODS = ("auto", "opaque", "single", "wyman", "raytrace")


def blender_runner(python: str | None, blender: str | None) -> tuple[list[str] | None, str]:
    """The command prefix that runs bench/blender_cycles.py (the job file is appended), and its
    name: the bpy wheel's interpreter when given, else the Blender executable, else None."""
    if python:
        if not os.access(python, os.X_OK):
            return None, f"{BLENDER_PYTHON_ENV}={python}: not an executable"
        return [python, str(WORKER), "--"], f"bpy wheel ({python})"
    if blender:
        return [blender, "-b", "--factory-startup", "--python-exit-code", "3", "-P", str(WORKER), "--"], \
            f"blender executable ({blender})"
    return None, ""


def method_label(method: str) -> str:
    """Column name of a method: `ours` for the default thumbnail (auto), else the method."""
    return "ours" if method == "auto" else method


def reference_key(job: dict, blender_version: str) -> str:
    """What a Cycles render depends on: the job (minus where it is written), the model file's
    bytes, the panorama's bytes, the worker script and the Blender version."""
    h = hashlib.sha256()
    h.update(json.dumps({k: v for k, v in job.items() if k not in ("out", "gltf", "panorama")},
                        sort_keys=True).encode())
    gltf = Path(job["gltf"])
    # a .gltf's buffers and images are files beside it
    files = sorted(p for p in gltf.parent.rglob("*") if p.is_file()) if gltf.suffix == ".gltf" else [gltf]
    for path in (*files, Path(job["panorama"]), WORKER):
        h.update(path.read_bytes())
    h.update(blender_version.encode())
    return h.hexdigest()


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--samples", type=Path, default=MODELS, help="folder of Khronos sample model folders")
    p.add_argument("--models", default=None, help="comma-separated model folder names (default: all)")
    p.add_argument("--size", type=int, default=128, help="image size (pixels, square)")
    p.add_argument("--spp", type=int, default=64, help="Cycles samples per pixel")
    p.add_argument("--env", default="footprint_court", help="bundled panorama")
    p.add_argument("--method", default="auto,raytrace",
                   help="comma-separated methods of ours to score (auto, opaque, single, wyman, raytrace)")
    p.add_argument("--integrator", choices=("tree", "path"), default="tree", help="raytrace's integrator")
    p.add_argument("--trace-samples", type=int, default=None,
                   help="raytrace integrator path: most paths per pixel (default: the option's)")
    p.add_argument("--blender-python", default=os.environ.get(BLENDER_PYTHON_ENV) or None,
                   help=f"an interpreter with the bpy wheel (default: ${BLENDER_PYTHON_ENV}); preferred over --blender")
    p.add_argument("--blender", default=shutil.which("blender"), help="Blender executable")
    p.add_argument("--fresh", action="store_true", help="render Cycles again even where a kept reference matches")
    p.add_argument("--sheet", type=Path, default=None,
                   help="write a contact sheet PNG (per model: our methods, Cycles, FLIP maps)")
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


def run_blender(runner: list[str], job: dict, workdir: Path, seconds: float) -> tuple[np.ndarray | None, str]:
    """Cycles' linear RGBA for `job`, or None and why."""
    job_path = workdir / "job.json"
    job_path.write_text(json.dumps(job))
    cmd = [*runner, str(job_path)]
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
    methods = [m.strip() for m in args.method.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise SystemExit(f"bench fidelity: --method {args.method!r}: unknown {', '.join(unknown) or 'empty'}"
                         f" (choose from {', '.join(METHODS)})")
    labels = [method_label(m) for m in methods]
    out = Path(args.out)
    (out / "fidelity").mkdir(parents=True, exist_ok=True)
    cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="bench-fidelity-"))
    work = Path(tempfile.mkdtemp(prefix="bench-fidelity-blender-"))
    env = bake_environment(args.env, cache, face_size=256)
    # No ground shadow: Cycles has no ground, and the shadow's coverage would put error-free
    # pixels into the mean.
    base = RenderOptions(width=args.size, height=args.size, background="transparent", shadow=0.0,
                         tonemap="aces", yaw=VIEW["yaw"], pitch=VIEW["pitch"], fov=VIEW["fov"])
    trace = {"integrator": args.integrator}
    if args.trace_samples:
        trace["samples"] = args.trace_samples
    per_method = {m: base.replace(method=m, **(trace if m == "raytrace" else {})) for m in methods}

    runner, runner_name = blender_runner(args.blender_python, args.blender)
    supported: set[str] = set()
    version = ""
    ours_only = f"{' vs '.join(labels)} only" if len(labels) > 1 else f"{labels[0]} only"
    if runner is None:
        note = runner_name or ("Blender is not installed (Debian: apt-get install -y blender, about 80 MB "
                               f"of packages; or the bpy wheel in its own venv, ${BLENDER_PYTHON_ENV})")
        note += f": no Cycles reference, {ours_only}"
    else:
        pano_path = work / "panorama.exr"
        pano = np.asarray(load_panorama(args.env).pixels, np.float32)[..., :3]
        write_exr(str(pano_path), np.dstack([blender_panorama(pano), np.ones(pano.shape[:2], np.float32)]))
        probe = work / "extensions.json"
        try:
            proc = subprocess.run([*runner, str(_write(work / "probe.json", {"query": "extensions", "out": str(probe)}))],
                                  capture_output=True, text=True, timeout=300)
            if not probe.is_file():
                raise ValueError((proc.stderr or proc.stdout).strip().splitlines()[-1:] or "no answer")
            info = json.loads(probe.read_text())
            supported, version = set(info["extensions"]), info["blender"]
            note = (f"reference Blender {version} Cycles through the {runner_name}, {args.spp} spp, "
                    f"importer handles {len(supported)} extensions")
        except (OSError, subprocess.SubprocessError, ValueError, KeyError) as exc:
            runner, note = None, f"Blender ({runner_name}) did not answer ({exc}): {ours_only}"
    trace_note = f"; raytrace integrator {args.integrator}" if "raytrace" in methods else ""
    print(f"# bench fidelity: {args.size} px, env {args.env}, yaw {VIEW['yaw']:g} pitch {VIEW['pitch']:g}, "
          f"methods {', '.join(methods)}{trace_note}; {note}")

    fields = ["model", *(f"{label}_flip" for label in labels),
              *(f"{labels[0]}_vs_{label}" for label in labels[1:]),
              *(f"{label}_ms" for label in labels), "cycles_s", "reference", "note"]
    rows = []
    sheet: list[tuple[str, list[tuple[str, np.ndarray]]]] = []
    jobs: list[tuple[str, Path | None]] = [
        ("calibration", scenes.write_glb(scenes.scene("mirror_sphere"), work / "mirror_sphere.glb"))]
    jobs += model_files(names, args.samples)
    for name, path in jobs:
        row = dict.fromkeys(fields, "")
        row["model"] = name
        rows.append(row)
        if path is None:
            row["note"] = "no .glb or .gltf in the folder"
            _print(row, labels)
            continue
        try:
            asset = bake_asset(path, cache)
        except AssetError as exc:
            row["note"] = f"not ingested: {exc}"
            _print(row, labels)
            continue
        images = {}
        for method, label in zip(methods, labels):
            t = time.perf_counter()
            images[label] = render(asset, env, per_method[method]).linear
            row[f"{label}_ms"] = f"{(time.perf_counter() - t) * 1e3:.0f}"
            _save_png(out / "fidelity" / f"{name}_{label}.png", images[label])
        for label in labels[1:]:
            row[f"{labels[0]}_vs_{label}"] = f"{flip_ldr(images[labels[0]], images[label]):.3f}"
        missing = sorted(set(extensions_used(path)) - supported) if runner else []
        ref = None
        if runner is None:
            row["note"] = "no Cycles reference"
        elif missing:
            row["note"] = "Blender's importer lacks " + ", ".join(missing) + ": not scored"
        else:
            camera = request_camera(asset, base)
            job = {"gltf": str(path), "panorama": str(pano_path), "out": str(work / f"{name}.exr"),
                   "size": args.size, "spp": args.spp, "camera_matrix": blender_camera(camera),
                   "fov": camera.fov, "clip": [camera.near * 0.5, camera.far * 2]}
            ref, row["reference"], row["cycles_s"], why = _reference(runner, job, version, out / "fidelity" / name,
                                                                     work, args)
            if ref is None:
                row["note"] = why
            else:
                for label in labels:
                    row[f"{label}_flip"] = f"{flip_ldr(images[label], ref):.3f}"
                _save_png(out / "fidelity" / f"{name}_cycles.png", ref)
        if args.sheet:
            sheet.append((name, [*images.items(), *([("Cycles", ref)] if ref is not None else [])]))
        _print(row, labels)
    scored = [r for r in rows if r[f"{labels[0]}_flip"] and r["model"] != "calibration"]
    if scored:
        means = ", ".join(f"{label} {np.mean([float(r[f'{label}_flip']) for r in scored]):.3f}" for label in labels)
        print(f"mean over {len(scored)} scored models: {means} (FLIP against Cycles)")
    with open(out / "fidelity.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    if args.sheet and sheet:
        contact_sheet(sheet, args.sheet, {r["model"]: r for r in rows}, labels)
        print(f"wrote {args.sheet}")
    print(f"wrote {out / 'fidelity.csv'} and images in {out / 'fidelity'}")
    return 0


def _reference(runner: list[str], job: dict, version: str, stem: Path, work: Path,
               args: argparse.Namespace) -> tuple[np.ndarray | None, str, str, str]:
    """(Cycles' image or None, 'rendered' / 'kept', seconds, why not): a kept render
    (STEM_cycles.exr beside STEM_cycles.key) is reused while its key matches."""
    key = reference_key(job, version)
    exr, key_file = stem.with_name(stem.name + "_cycles.exr"), stem.with_name(stem.name + "_cycles.key")
    if not args.fresh and exr.is_file() and key_file.is_file() and key_file.read_text().strip() == key:
        return read_exr(str(exr)), "kept", "", ""
    t = time.perf_counter()
    ref, why = run_blender(runner, job, work, args.blender_seconds)
    seconds = f"{time.perf_counter() - t:.1f}"
    if ref is not None:
        shutil.copyfile(job["out"], exr)
        key_file.write_text(key + "\n")
    return ref, "rendered", seconds, why


def contact_sheet(entries: list[tuple[str, list[tuple[str, np.ndarray]]]], path: Path,
                  rows: dict[str, dict], labels: list[str]) -> None:
    """One row per model: each image (tone-mapped over a mid grey) captioned with its FLIP
    against Cycles, then Cycles, then the FLIP map of each method against it."""
    import flip_evaluator
    from PIL import Image, ImageDraw

    tile, caption = 128, 14
    columns = max(len(images) + (len(images) - 1 if any(n == "Cycles" for n, _ in images) else 0)
                  for _, images in entries)
    sheet = Image.new("RGB", (140 + columns * tile, len(entries) * (tile + caption)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)

    def over_grey(linear: np.ndarray) -> Image.Image:
        rgb = display(linear)
        a = np.clip(linear[..., 3:4], 0, 1)
        return Image.fromarray(np.round((rgb + (1 - a) * 0.5) * 255).clip(0, 255).astype(np.uint8))

    for i, (name, images) in enumerate(entries):
        y = i * (tile + caption)
        draw.text((4, y + tile // 2), name[:22], fill=(0, 0, 0))
        ref = dict(images).get("Cycles")
        cells: list[tuple[str, Image.Image]] = []
        for label, img in images:
            flip = rows[name].get(f"{label}_flip", "")
            cells.append((f"{label} {flip}" if flip else label, over_grey(img)))
        if ref is not None:
            for label, img in images:
                if label == "Cycles":
                    continue
                emap = flip_evaluator.evaluate(np.ascontiguousarray(display(ref)), np.ascontiguousarray(display(img)),
                                               "LDR", inputsRGB=True, applyMagma=True, computeMeanError=False)[0]
                cells.append((f"FLIP {label}", Image.fromarray(np.round(np.asarray(emap)[..., :3] * 255)
                                                               .clip(0, 255).astype(np.uint8))))
        for j, (text, im) in enumerate(cells):
            x = 140 + j * tile
            sheet.paste(im.resize((tile, tile), Image.Resampling.NEAREST), (x, y))
            draw.text((x + 2, y + tile), text, fill=(0, 0, 0))
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)


def _write(path: Path, obj) -> Path:
    path.write_text(json.dumps(obj))
    return path


def _print(row: dict, labels: list[str]) -> None:
    flips = "  ".join(f"{label} {row[f'{label}_flip'] or '-':>6}" for label in labels)
    pairs = "  ".join(f"{labels[0]}~{label} {row[f'{labels[0]}_vs_{label}'] or '-':>6}" for label in labels[1:])
    times = " / ".join(f"{row[f'{label}_ms'] or '-'} ms" for label in labels)
    cycles = f"Cycles {row['cycles_s'] or '-'} s" + (" kept" if row["reference"] == "kept" else "")
    print(f"{row['model']:<24} {flips}  {pairs}  ({times} / {cycles})  {row['note']}", flush=True)
