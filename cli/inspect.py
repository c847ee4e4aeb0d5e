"""`asset-preview inspect PATH [--json]`: what an asset holds, after ingest's validation.

Exit 0 on success; an AssetError becomes `error: FILE: REASON` and exit 3 (cli.main's
run_guarded); argparse's usage errors exit 2.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from cli import sandbox


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", type=Path, metavar="PATH", help="asset file (glTF, USD, OBJ/PLY/STL)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--variant-set", action="append", default=[], metavar="[PRIM:]SET=NAME",
                        help="USD: select a variant (repeatable; no PRIM: the default prim's set)")
    sandbox.add_argument(parser)


def summary(scene) -> dict:
    """The JSON-ready summary of a Scene; counts are as rendered (every instance)."""
    materials = []
    for m in scene.materials:
        materials.append({
            "name": m.name, "class": m.material_class, "alpha_mode": m.alpha_mode,
            "base_color": list(m.base_color), "metallic": m.metallic, "roughness": m.roughness,
            "emissive": list(m.emissive), "emissive_strength": m.emissive_strength,
            "transmission": m.transmission, "ior": m.ior, "thickness": m.thickness,
            "double_sided": m.double_sided, "unlit": m.unlit,
            "textures": sorted(m.texture_refs()),
        })
    return {
        "file": scene.source,
        "format": scene.format,
        "meshes": len(scene.meshes),
        "instances": len(scene.instances),
        "triangles": scene.triangle_count,
        "vertices": sum(len(scene.meshes[i.mesh].positions) for i in scene.instances),
        "materials": materials,
        "textures": len(scene.textures),
        "lights": len(scene.lights),
        "environment": scene.environment,
        "bounds": scene.bounds.tolist(),
        "extensions": dict(scene.extensions),  # extensionsUsed -> supported|partial|ignored
        "variants": list(scene.variants),
        "variant_sets": list(scene.variant_sets),  # USD: {prim, set, variants, selection}
        "cameras": [{"index": i, "name": c.name, "type": c.type,
                     "position": [round(float(v), 6) for v in c.matrix[:3, 3]]}
                    for i, c in enumerate(scene.cameras)],
        "animations": list(scene.animations),  # core.animation.Animation.summary()
        "time_range": scene.time_range,  # USD: start/end time codes, timeCodesPerSecond
        "skel_animations": list(scene.skel_animations),  # USD: {path, joints, blend_shapes, samples, first, last}
        "backdrop": sorted({scene.meshes[i.mesh].name for i in scene.instances if i.backdrop}),
        "warnings": list(scene.warnings),
        "files": list(scene.files),
    }


def run(args: argparse.Namespace) -> int:
    from pipeline.ingest import load_scene

    info = summary(load_scene(args.path, root=sandbox.root(args), variant_sets=tuple(args.variant_set)))
    if args.json:
        print(json.dumps(info))
        return 0
    lo, hi = info["bounds"]
    print(f"{info['file']} ({info['format']})")
    print(f"  meshes {info['meshes']}, instances {info['instances']}, triangles "
          f"{info['triangles']}, vertices {info['vertices']}, textures {info['textures']}, "
          f"lights {info['lights']}")
    print("  bounds " + " .. ".join("(" + ", ".join(f"{v:.4g}" for v in b) + ")" for b in (lo, hi)))
    if info["environment"]:
        print(f"  environment {info['environment']} (dome light)")
    for m in info["materials"]:
        tex = f" textures: {', '.join(m['textures'])}" if m["textures"] else ""
        print(f"  material {m['name']!r}: {m['class']}{tex}")
    if info["extensions"]:
        print("  extensions " + ", ".join(f"{k} ({v})" for k, v in info["extensions"].items()))
    if info["variants"]:
        print("  variants " + ", ".join(map(repr, info["variants"])) + " (render --variant NAME)")
    for v in info["variant_sets"]:
        print(f"  variant set {v['prim']}:{v['set']} = {v['selection'] or '(none)'!r} of "
              + ", ".join(map(repr, v["variants"])) + " (--variant-set PRIM:SET=NAME)")
    for c in info["cameras"]:
        print(f"  camera {c['index']} {c['name']!r}: {c['type']} (render --camera {c['index']})")
    for i, a in enumerate(info["animations"]):
        nodes = len({t["node"] for t in a["targets"] if "pointer" not in t})
        pointers = sum("pointer" in t for t in a["targets"])  # KHR_animation_pointer
        also = f" and {pointers} material / light / camera values" if pointers else ""
        print(f"  animation {i} {a['name']!r}: {a['duration']:.3g} s, {a['channels']} channels "
              f"driving {nodes} nodes{also} (render --animation {i})")
    if info["time_range"]:
        r = info["time_range"]
        print(f"  time codes {r['start']:g} .. {r['end']:g} at {r['time_codes_per_second']:g} "
              f"per second ({r['duration']:.3g} s; render --time SECONDS)")
    for a in info["skel_animations"]:
        span = f", codes {a['first']:g} .. {a['last']:g}" if a["samples"] else ""
        shapes = f", blend shapes {', '.join(map(repr, a['blend_shapes']))}" if a["blend_shapes"] else ""
        print(f"  skel animation {a['path']}: {a['joints']} joints{shapes}, {a['samples']} time samples{span}")
    if info["backdrop"]:
        print("  backdrop (not framed): " + ", ".join(map(repr, info["backdrop"])))
    for w in info["warnings"]:
        print(f"  warning: {w}")
    return 0
