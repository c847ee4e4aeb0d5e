"""The frames of an animated preview: which times to sample, and the asset posed at each.

A still at one `--time` is an ordinary bake with the `moment` bake option (cached like any
other). An `--animate` preview needs many poses that are seen once: each is ingested and
built in memory (pipeline.bake.build_baked), not stored in the cache, and shares the rest
bake's textures, which no pose changes.
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from core.animation import Moment, requested, select
from core.baked import BakedAsset
from core.errors import NotInAsset
from core.options import MAX_FRAMES
from pipeline.bake import POSED_OPTIONS, build_baked
from pipeline.ingest import load_scene
from pipeline.limits import Limits

log = logging.getLogger(__name__)



def frame_times(base: BakedAsset, fps: float, animation: str | None = None) -> tuple[list[float], dict]:
    """Sample times (seconds, as core.animation.Moment reads them) every 1/fps over the
    animation `base` (the rest bake) has, first frame at its start, the end left out (a loop's
    last frame is its first); and what was played, for the plan."""
    m = base.manifest or {}
    if m.get("animations"):
        anim = select(m["animations"], animation, base.source)
        start, duration, name = float(anim["start"]), float(anim["duration"]), anim["name"]
    elif m.get("time_range"):  # USD: seconds from the stage's start
        start, duration, name = 0.0, float(m["time_range"]["duration"]), None
    else:
        raise NotInAsset(base.source, "has no animation or time samples to play (--animate)")
    count = max(1, min(MAX_FRAMES, round(duration * fps)))
    times = [start + i / fps for i in range(count)]
    return times, {"animation": name, "start": start, "duration": duration, "fps": fps,
                   "frames": count, "truncated": count < round(duration * fps)}


def posed(path, base: BakedAsset, moment: Moment, root=None, limits: Limits | None = None) -> BakedAsset:
    """`path` posed at `moment`, built in memory with `base`'s textures; its key is `base`'s
    and the moment's (GPU uploads are by key: each pose is its own)."""
    opts = (base.manifest or {}).get("options", {})  # the same variants and purposes as base
    scene = load_scene(Path(path), limits, root, moment=moment,
                       variant_sets=tuple(opts.get("variant_sets", ())),
                       purposes=tuple(opts.get("purposes", ("render",))),
                       draw_mode=opts.get("draw_mode", "authored"))
    layouts = [t.udim for t in scene.textures]  # UDIM meshes are remapped as base's were
    scene.textures = []  # not decoded again: no pose changes them, base's are used
    key = f"{base.key}@{moment.animation or ''}:{float(moment.time):.6f}"
    baked = build_baked(scene, key, {**opts, **POSED_OPTIONS,
                                     "moment": dataclasses.asdict(moment)}, layouts)
    baked.textures = base.textures
    return baked


def frames(path, base: BakedAsset, times: list[float], animation: str | None = None, root=None,
           limits: Limits | None = None) -> list[BakedAsset]:
    """`path` posed at each of `times` (seconds of `animation`). glTF: one Rig (pipeline.gltf.rig)
    read once and posed per frame, the frames sharing one GPU upload; USD likewise through one
    UsdRig (pipeline.usd.rig); a stage or glTF its rig cannot pose: each frame read whole (posed)."""
    if Path(path).suffix.lower() in (".gltf", ".glb"):
        from pipeline.gltf.rig import Rig, RigUnsupported
        try:
            rig = Rig(path, base, animation, root, limits)
        except RigUnsupported as exc:
            log.info("%s: each frame read whole: %s", path, exc)
        else:
            return [rig.pose(t, f"{base.key}@{animation or ''}:{t:.6f}") for t in times]
    elif Path(path).suffix.lower() in (".usd", ".usda", ".usdc", ".usdz") and times:
        from pipeline.usd.rig import RigUnsupported as UsdRigUnsupported
        from pipeline.usd.rig import UsdRig
        try:
            usd_rig = UsdRig(path, base, times[0], root, limits)
        except UsdRigUnsupported as exc:
            log.info("%s: each frame read whole: %s", path, exc)
        else:
            try:
                return [usd_rig.pose(t, f"{base.key}@:{t:.6f}") for t in times]
            except UsdRigUnsupported as exc:  # found at a later frame (its triangles changed)
                log.info("%s: each frame read whole: %s", path, exc)
            finally:
                usd_rig.close()
    return [posed(path, base, Moment(t, animation), root, limits) for t in times]


def poses_for(path, base: BakedAsset, options, root=None,
              limits: Limits | None = None) -> tuple[list[BakedAsset], dict | None]:
    """The poses a request (core.options.RenderOptions) needs of `path`, whose rest bake is
    `base`: every frame's for `animate` with what was played, the one pose of its `time`, or
    `base` itself when it asks for neither."""
    if options.animate:
        times, motion = frame_times(base, options.animate, options.animation)
        return frames(path, base, times, options.animation, root, limits), motion
    moment = requested(options)
    return [base if moment is None else posed(path, base, moment, root, limits)], None
