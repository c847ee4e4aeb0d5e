"""`asset-preview bench usd`: every USD stage of ../shared/assets/usd and ../shared/assets/usd-wg,
rendered by us and by Hydra Storm (usdview's renderer) from the same camera under the same light.

Method (docs/usd.md, "Storm reference"):
- The stages are copied into a scratch folder; the entry points are the USD files no other file
  there references, sublayers or payloads (asset-bake's rule). Beside each one goes a wrapper
  layer (bench/storm.py) with /BenchCamera framing its bounds and, for a stage without lights,
  a uniform white dome; both renderers render the wrapper through that camera.
- Storm: FrameRecorder, no camera light, sRGB colour correction, no tone curve; ours:
  `--tonemap none` (sRGB encoding of the clamped linear frame), transparent background. Both
  are composited over the same grey, in display space with straight alpha (Storm's PNG holds
  premultiplied colour: unpremultiplied in linear first), and compared with LDR-FLIP (Storm is the reference); the
  FLIP mean is over the frame.
- Time to first image: cold = a new process (ours: `python -m bench.usd_cold`, which is
  `asset-preview render` plus a breakdown of where its time goes, with an empty cache and the
  project's bytecode compiled first, as an installed package has it; Storm:
  bench/storm_worker.py) from spawn to the image on disk; warm = a second image of the same
  stage in a process that has already drawn it (ours: bake from the warm cache + render, in
  this process; Storm: stage open + Record in its process).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.assets import REPO, SHARED
from bench.storm import CAMERA, copy_tree, render_storm, storm_python, write_wrapper

SOURCES = ("usd", "usd-wg")
PHASES = ("python", "pxr_import", "our_import", "composition", "materialx", "bake", "environment",
          "first_frame", "other")
GREY = 0.5  # both frames go over the same background before FLIP


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--assets", type=Path, default=SHARED, help="folder holding usd/ and usd-wg/")
    p.add_argument("--stages", default=None, help="comma-separated substrings of stage paths to keep")
    p.add_argument("--size", type=int, default=256, help="image size (pixels, square)")
    p.add_argument("--storm-python", default=None,
                   help="the Storm interpreter (default: $ASSET_PREVIEW_STORM_PYTHON)")
    p.add_argument("--out", type=Path, default=REPO / "bench" / "results",
                   help="folder for usd_storm.csv, usd_storm.json and usd_storm.png")
    p.add_argument("--timeout", type=float, default=300.0, help="seconds per render before giving up")
    p.add_argument("--storm-complexity", type=float, default=1.0,
                   help="usdview's complexity for Storm: 1.0 (its default) draws subdivision cages "
                        "unrefined, 1.2 refines them two levels as ours does a small cage")
    p.add_argument("--keep-images", type=Path, default=None,
                   help="copy each stage's ours/Storm PNGs here (to look at them or compare runs)")
    p.add_argument("--method", default="auto",
                   help="our render method (`render --method`: auto, raytrace, ...); Storm is the same")


def entry_points(folder: Path) -> list[Path]:
    """USD files under `folder` that no other one uses (asset-bake's rule), .usdz included."""
    from pipeline.library import usd_parts

    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz")
                   and not p.name.endswith(".bench.usda"))
    parts = usd_parts(files)
    return [p for p in files if str(p) not in parts]


def _over_grey(path: Path, size: int, premultiplied: bool = False) -> np.ndarray:
    from PIL import Image
    im = Image.open(path).convert("RGBA")
    if im.size != (size, size):
        im = im.resize((size, size), Image.Resampling.BILINEAR)
    return over_grey(np.asarray(im), premultiplied)


def ldr_flip(ours: np.ndarray, ref: np.ndarray) -> tuple[float, np.ndarray]:
    """(mean LDR-FLIP of `ours` against `ref`, both sRGB 0..1, magma error map as uint8)."""
    import flip_evaluator
    emap, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref, np.float32),
                                            np.ascontiguousarray(ours, np.float32), "LDR",
                                            inputsRGB=True, applyMagma=True, computeMeanError=True)
    return float(mean), np.clip(np.asarray(emap) * 255, 0, 255).astype(np.uint8)


def _ours_cold(wrapper, out: Path, cache: Path, size: int, root: Path, timeout: float,
               method: str = "auto") -> dict:
    cmd = [sys.executable, "-m", "bench.usd_cold", str(wrapper.path), "--camera", CAMERA, "--out", str(out),
           "--cache", str(cache), "--tonemap", "none", "--background", "transparent", "--size", str(size),
           "--shadow", "0", "--sandbox", str(root), "--method", method]
    if wrapper.black_env:
        cmd += ["--env", str(wrapper.black_env)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    start = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=REPO)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    wall = time.perf_counter() - start
    lines = proc.stdout.strip().splitlines()
    phases = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {}
    if proc.returncode or not out.is_file():
        msg = [ln for ln in proc.stderr.strip().splitlines() if ln.startswith("error")] or \
            proc.stderr.strip().splitlines()[-1:]
        return {"error": f"exit {proc.returncode}: {' | '.join(msg)[:300]}", "phases": phases}
    warnings = [ln for ln in proc.stderr.splitlines() if "WARNING" in ln or "warning" in ln]
    return {"cold_s": wall, "cold_cpu_s": phases.get("cpu_s"), "phases": phases, "warnings": warnings[:5]}


def render_ours(wrapper, cache: Path, size: int, root: Path, method: str = "auto"):
    """Our Frame of the wrapper, in this process, as the cold command renders it."""
    from core.options import from_request
    from pipeline.bake import bake_asset, bake_environment
    from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
    from pipeline.lighting import dome_texture
    from renderer.methods.auto import environment_face_size
    from renderer.raster.render import render

    options = from_request({"width": size, "height": size, "camera": CAMERA, "tonemap": "none",
                            "background": "transparent", "shadow": 0.0, "method": method})
    asset = bake_asset(str(wrapper.path), str(cache), root=str(root))
    face, _ = environment_face_size(asset, options)
    source = str(wrapper.black_env) if wrapper.black_env else (dome_texture(asset, str(wrapper.path))
                                                               or DEFAULT_ENVIRONMENT)
    env = bake_environment(source, str(cache), face_size=face)
    return render(asset, env, options)


def _ours_warm(wrapper, cache: Path, size: int, root: Path, method: str = "auto") -> float:
    """A second image in this process from the warm cache (the first one warms GL and shaders)."""
    render_ours(wrapper, cache, size, root, method).encode("png")
    start = time.perf_counter()
    render_ours(wrapper, cache, size, root, method).encode("png")  # Storm's Record writes a PNG too
    return time.perf_counter() - start


def over_grey(rgba8: np.ndarray, premultiplied: bool = False) -> np.ndarray:
    """sRGB 0..1 of `rgba8` over GREY, blended in display space as ours composites a
    background. Ours is straight alpha; Storm's FrameRecorder writes the sRGB encoding of
    premultiplied linear colour (`premultiplied`: a half-transparent white card comes out as
    sRGB(0.5 x white) at alpha 0.5), so its colour is divided by alpha in linear first."""
    a = rgba8.astype(np.float32) / 255.0
    rgb, alpha = a[..., :3], a[..., 3:]
    if premultiplied:
        from core.colour import srgb_encode, srgb_to_linear
        linear = srgb_to_linear(rgba8[..., :3])
        rgb = srgb_encode(np.where(alpha > 0, linear / np.maximum(alpha, 1e-6), 0.0)).astype(np.float32)
    return rgb * alpha + GREY * (1.0 - alpha)


def compile_sources() -> None:
    """Byte-compile the project's modules (into their __pycache__, ignored by git), as
    installing a wheel does, and fill numba's kernel cache, as `make install` does: with
    PYTHONDONTWRITEBYTECODE set, or a read-only checkout, every cold process would compile our
    modules again (0.2-0.3 s of CPU), and the first stage with an interior bake would JIT the
    kernels (a minute), which neither an installed package nor Storm (bpy ships its .pyc) pays."""
    import compileall
    for package in ("core", "gl", "pipeline", "renderer", "service", "cli", "bench", "shaders"):
        compileall.compile_dir(str(REPO / package), quiet=1)
    for module in ("renderer.methods.trace_kernel", "pipeline.interior.vectors"):
        subprocess.run([sys.executable, "-m", module], cwd=REPO, check=True, capture_output=True)


def run(args: argparse.Namespace) -> int:
    python, why = (args.storm_python, "") if args.storm_python else storm_python()
    if python is None:
        print(f"bench usd: {why}; Storm columns are empty", file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    compile_sources()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-usd-") as tmp:
        work = Path(tmp)
        stages: list[tuple[str, Path, Path]] = []
        for src in SOURCES:
            if not (args.assets / src).is_dir():
                print(f"bench usd: {args.assets / src}: not there; skipped", file=sys.stderr)
                continue
            copy = copy_tree(args.assets / src, work / src)
            for p in entry_points(copy):
                name = str(p.relative_to(work))
                if not args.stages or any(s in name for s in args.stages.split(",")):
                    stages.append((name, p, copy))  # a stage may read its whole collection
        images = work / "images"
        images.mkdir()
        for i, (name, stage, root) in enumerate(stages):
            slug = name.replace("/", "__")
            row: dict = {"stage": name}
            try:
                wrapper = write_wrapper(stage)
            except Exception as exc:  # pxr itself cannot open it: both renderers would refuse
                row["error"] = f"wrapper: {str(exc).strip().splitlines()[-1][:200]}"
                rows.append(row)
                print(f"[{i + 1}/{len(stages)}] {name}: {row['error']}", flush=True)
                continue
            row["light"] = ("stage dome" if wrapper.own_dome else "stage lights") if wrapper.own_lights \
                else "uniform dome"
            ours_png, storm_png = images / f"{slug}.ours.png", images / f"{slug}.storm.png"
            cache = work / "cache" / slug
            ours = _ours_cold(wrapper, ours_png, cache, args.size, root, args.timeout, args.method)
            row.update({"ours_cold_s": ours.get("cold_s"), "ours_cold_cpu_s": ours.get("cold_cpu_s"), "ours_error": ours.get("error", ""),
                        **{f"phase_{k}": ours.get("phases", {}).get(k) for k in PHASES},
                        **{f"cpu_phase_{k}": ours.get("phases", {}).get("cpu", {}).get(k) for k in PHASES}})
            if "cold_s" in ours:
                try:
                    row["ours_warm_s"] = _ours_warm(wrapper, cache, args.size, root, args.method)
                except Exception as exc:
                    row["ours_error"] = f"warm: {exc}"
            if python:
                storm = render_storm(python, wrapper.path, storm_png, args.size, timeout=args.timeout,
                                     complexity=args.storm_complexity)
                row.update({"storm_cold_s": None if math.isnan(storm.first_image_s) else storm.first_image_s,
                            "storm_cold_cpu_s": storm.first_image_cpu_s, "storm_warm_s": storm.warm_s, "storm_error": storm.error})
            if storm_png.is_file():
                from PIL import Image
                row["storm_drew"] = bool(np.asarray(Image.open(storm_png).convert("RGBA"))[..., 3].max() > 0)
            if ours_png.is_file() and storm_png.is_file():
                a, b = _over_grey(ours_png, args.size), _over_grey(storm_png, args.size, premultiplied=True)
                row["flip"], emap = ldr_flip(a, b)
                row["_images"] = (a, b, emap)
            elif ours_png.is_file():
                row["_images"] = (_over_grey(ours_png, args.size), None, None)
            elif storm_png.is_file():
                row["_images"] = (None, _over_grey(storm_png, args.size, premultiplied=True), None)
            if args.keep_images:
                import shutil
                args.keep_images.mkdir(parents=True, exist_ok=True)
                for png in (ours_png, storm_png):
                    if png.is_file():
                        shutil.copy2(png, args.keep_images / png.name)
            rows.append(row)
            print(f"[{i + 1}/{len(stages)}] {name}: flip {_fmt(row.get('flip'))} ours {_fmt(row.get('ours_cold_s'))}/"
                  f"{_fmt(row.get('ours_warm_s'))} s storm {_fmt(row.get('storm_cold_s'))}/"
                  f"{_fmt(row.get('storm_warm_s'))} s {row.get('ours_error', '')} {row.get('storm_error', '')}",
                  flush=True)
    sheet = contact_sheet(rows, args.size)
    sheet.save(args.out / "usd_storm.png")
    _write_tables(rows, args.out)
    print(summary(rows))
    print(f"wrote {args.out / 'usd_storm.png'}, usd_storm.csv, usd_storm.json")
    return 0


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def _median(rows: list[dict], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return statistics.median(vals) if vals else None


def summary(rows: list[dict]) -> str:
    both = [r for r in rows if r.get("flip") is not None]
    timed = [r for r in rows if r.get("ours_cold_s") is not None and r.get("storm_cold_s") is not None]
    refused = [r for r in rows if r.get("ours_error") and r.get("storm_drew")]
    empty = [r for r in rows if r.get("ours_error") and r.get("storm_drew") is False]
    lines = [f"stages: {len(rows)}; both rendered: {len(both)}; nothing to draw for either (ours refuses, "
             f"Storm's frame is empty): {len(empty)}; ours failed where Storm drew: {len(refused)} "
             f"{[r['stage'] for r in refused]}; Storm failed: {sum(1 for r in rows if r.get('storm_error'))}; "
             f"pxr cannot open: {sum(1 for r in rows if r.get('error'))}"]
    if both:
        lines.append(f"FLIP (LDR, Storm reference): median {statistics.median(r['flip'] for r in both):.3f}, "
                     f"mean {statistics.mean(r['flip'] for r in both):.3f}")
    for label, sub in (("over the stages both rendered", timed),):
        oc, sc = _median(sub, "ours_cold_s"), _median(sub, "storm_cold_s")
        ow, sw = _median(sub, "ours_warm_s"), _median(sub, "storm_warm_s")
        if oc and sc:
            lines.append(f"cold first image {label}: ours median {oc:.2f} s, Storm {sc:.2f} s, ratio {oc / sc:.2f}")
        ocpu, scpu = _median(sub, "ours_cold_cpu_s"), _median(sub, "storm_cold_cpu_s")
        if ocpu and scpu:
            lines.append(f"cold first image, CPU seconds (all threads): ours median {ocpu:.2f}, Storm {scpu:.2f}, "
                         f"ratio {ocpu / scpu:.2f}")
        if ow and sw:
            lines.append(f"warm image: ours median {ow:.3f} s, Storm {sw:.3f} s, ratio {ow / sw:.2f}")
    ph = {k: _median(timed, f"phase_{k}") for k in PHASES}
    if any(v is not None for v in ph.values()):
        lines.append("our cold time over those stages, median per phase (s): " +
                     ", ".join(f"{k} {v:.3f}" for k, v in ph.items() if v is not None))
    ph = {k: _median(timed, f"cpu_phase_{k}") for k in PHASES}
    if any(v is not None for v in ph.values()):
        lines.append("the same in CPU seconds (all threads): " +
                     ", ".join(f"{k} {v:.3f}" for k, v in ph.items() if v is not None))
    worst = sorted(both, key=lambda r: -r["flip"])[:10]
    lines.append("largest FLIP: " + "; ".join(f"{r['stage']} {r['flip']:.3f}" for r in worst))
    return "\n".join(lines)


def _write_tables(rows: list[dict], out: Path) -> None:
    clean = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    keys = list(dict.fromkeys(k for r in clean for k in r))
    with open(out / "usd_storm.csv", "w", newline="") as f:
        w = csv.DictWriter(f, keys)
        w.writeheader()
        for r in clean:
            w.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()})
    (out / "usd_storm.json").write_text(json.dumps({"rows": clean, "summary": summary(rows)}, indent=1))


def contact_sheet(rows: list[dict], size: int, per_row: int = 3):
    """ours | Storm | FLIP per stage, `per_row` stages across, each labelled."""
    from PIL import Image, ImageDraw
    label_h = 14
    cell_w, cell_h = 3 * size, size + label_h
    n = max(len(rows), 1)
    sheet = Image.new("RGB", (per_row * cell_w, math.ceil(n / per_row) * cell_h), (40, 40, 40))
    draw = ImageDraw.Draw(sheet)
    for i, r in enumerate(rows):
        x, y = (i % per_row) * cell_w, (i // per_row) * cell_h
        a, b, e = r.get("_images", (None, None, None))
        for j, img in enumerate((a, b, e)):
            if img is None:
                continue
            arr = img if img.dtype == np.uint8 else (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
            sheet.paste(Image.fromarray(arr[..., :3]), (x + j * size, y + label_h))
        flip = r.get("flip")
        err = ("both empty" if r.get("storm_drew") is False and r.get("ours_error") else
               (r.get("ours_error") or r.get("storm_error") or r.get("error") or ""))[:60]
        text = f"{r['stage'].split('/', 1)[-1][-52:]}  " + (f"FLIP {flip:.3f}" if flip is not None else err)
        draw.text((x + 2, y + 1), text, fill=(230, 230, 230))
    return sheet
