"""Several frames of one asset from one upload and one bake: a turntable (`turntable` = N
frames around +Y, written as an animated WebP or GIF) and a labelled sheet of views.

The asset and the environment are uploaded on the first frame and stay on the GPU
(renderer.raster.gpu keeps them), so frame k costs a draw and a readback, not a bake or an upload.
"""
from __future__ import annotations

import dataclasses
import io
import time

import numpy as np
from PIL import Image

from core.baked import BakedAsset, BakedEnvironment
from core.options import RenderOptions
from renderer.frame import WEBP_SETTINGS, Frame, FrameTimings, alpha_is_mask
from renderer.raster import gpu
from renderer.raster.render import render
from renderer.view.framing import asset_camera

ANIMATED_FORMATS = ("webp", "gif", "png")  # png: APNG
FRAME_MS = 80  # per turntable frame: 24 frames turn once in about two seconds
VIEWS = (("front", 0.0, 0.0), ("side", 90.0, 0.0), ("top", 0.0, 89.9), ("three-quarter", None, None))


def turntable_angles(options: RenderOptions) -> list[float]:
    """Yaw of each frame: evenly around +Y from options.yaw, so the last frame's neighbour in
    angle is the first (the animation loops without a jump)."""
    n = max(int(options.turntable), 1)
    return [options.yaw + 360.0 * i / n for i in range(n)]


def turntable_distance(asset: BakedAsset, options: RenderOptions) -> float:
    """One camera distance for every frame (no zoom as it turns): the farthest of each
    angle's screen-space fit, turning about the bounds' centre."""
    if options.distance is not None:
        return options.distance
    centre = np.asarray(asset.bounds, np.float64).mean(axis=0)
    far = 0.0
    for yaw in turntable_angles(options):
        cam = asset_camera(asset, dataclasses.replace(options, yaw=yaw))[0]
        # The fit may shift the camera sideways; about the centre it needs that much more room.
        far = max(far, float(np.linalg.norm(cam.position - centre)) * 1.05)
    return far


def render_turntable(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions,
                     keep_linear: bool = True) -> list[Frame]:
    """options.turntable frames around +Y (at least one). With keep_linear False the frames
    hold their display pixels only (an animation's encoder reads no more): a kept frame's
    linear image costs a pass of its own before the next frame (renderer.raster.final)."""
    distance = turntable_distance(asset, options)
    uploads = dict(gpu.stats)
    frames = []
    for yaw in turntable_angles(options):
        frame = render(asset, env, dataclasses.replace(
            options, yaw=yaw, distance=distance, turntable=0, views=False))
        if not keep_linear:  # the frame's pending linear image goes with it, never drawn
            frame = Frame(_no_linear, frame.rgba8, frame.plan, frame.timings, frame.alpha_is_mask)
        frames.append(frame)
    frames[0].plan["turntable"] = {
        "frames": len(frames), "distance": distance, "frame_ms": FRAME_MS,
        "uploaded": {k: gpu.stats[k] - uploads[k] for k in ("asset_uploads", "environment_uploads")}}
    return frames


def _no_linear():
    raise RuntimeError("a turntable rendered with keep_linear=False keeps display pixels only")


def encode_animation(frames: list[Frame], fmt: str = "webp", quality: int | None = None,
                     frame_ms: float = FRAME_MS) -> bytes:
    """An animated WebP (lossy at `quality`, default 85), GIF or APNG that loops forever,
    `frame_ms` per frame."""
    if fmt not in ANIMATED_FORMATS:
        raise ValueError(f"animated format {fmt!r}: use {' or '.join(ANIMATED_FORMATS)}")
    images = [Image.fromarray(f.rgba8, "RGBA") for f in frames]
    out = io.BytesIO()
    kw = {"save_all": True, "append_images": images[1:], "duration": int(round(frame_ms)), "loop": 0}
    if fmt == "png":
        images[0].save(out, "PNG", **kw)
    elif fmt == "webp":
        images[0].save(out, "WEBP", quality=85 if quality is None else quality, **WEBP_SETTINGS, **kw)
    else:
        rgb = [im.convert("RGB") for im in images]
        rgb[0].save(out, "GIF", **{**kw, "append_images": rgb[1:]}, optimize=False, disposal=2)
    return out.getvalue()


def motion_camera(assets: list[BakedAsset], options: RenderOptions) -> RenderOptions:
    """`options` with one target and distance for every frame of a motion, so the whole
    motion stays in the frame and the camera neither zooms nor pans: the framing of all
    frames' geometry at once (a stand-in asset holding every pose), and, turning, the
    turntable's distance of that stand-in about its centre."""
    if options.camera is not None:  # the asset's own camera frames it
        return options
    lo = np.min([np.asarray(a.bounds, np.float64)[0] for a in assets], axis=0)
    hi = np.max([np.asarray(a.bounds, np.float64)[1] for a in assets], axis=0)
    hulls = [a.hull for a in assets if a.hull is not None and len(a.hull)]
    whole = dataclasses.replace(
        assets[0], key=f"{assets[0].key}#motion{len(assets)}", textures=[],
        meshes=[m for a in assets for m in a.meshes], bounds=np.stack([lo, hi]),
        hull=np.concatenate(hulls) if len(hulls) == len(assets) else None)
    if options.turntable:
        centre = (lo + hi) / 2 if options.target is None else np.asarray(options.target)
        return dataclasses.replace(options, target=_point(centre),
                                   distance=turntable_distance(whole, options))
    cam = asset_camera(whole, options)[0]
    return dataclasses.replace(options, target=_point(cam.target),
                               distance=float(np.linalg.norm(cam.position - cam.target)))


def _point(p: np.ndarray) -> tuple[float, float, float]:
    return (float(p[0]), float(p[1]), float(p[2]))


def render_animation(assets: list[BakedAsset], env: BakedEnvironment, options: RenderOptions,
                     motion: dict) -> list[Frame]:
    """One frame per posed asset (pipeline.animate), seen by one camera that covers the whole
    motion (motion_camera); with options.turntable the camera also turns once about +Y over
    the animation. `motion` (what was played: pipeline.animate.frame_times) goes in the plan."""
    fixed = motion_camera(assets, options)
    uploads = dict(gpu.stats)
    frames = []
    for i, asset in enumerate(assets):
        yaw = options.yaw + (360.0 * i / len(assets) if options.turntable else 0.0)
        frame = render(asset, env, dataclasses.replace(fixed, yaw=yaw, turntable=0, animate=None))
        frames.append(Frame(_no_linear, frame.rgba8, frame.plan, frame.timings, frame.alpha_is_mask))
    frames[0].plan["animate"] = {
        **motion, "target": list(fixed.target or ()), "distance": fixed.distance,
        "frame_ms": 1000.0 / float(options.animate or 1),
        "uploaded": {k: gpu.stats[k] - uploads[k] for k in ("asset_uploads", "environment_uploads")}}
    return frames


def render_views(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions) -> Frame:
    """A 2 x 2 sheet of front, side, top and three-quarter views, each labelled, the size of
    one frame of `options` (each view is a quarter of it). Its linear image, which a sheet
    served as PNG or WebP never needs, is made only when asked for: the views are drawn again
    (the same pixels) and their linear images placed as the display ones are."""
    t0 = time.perf_counter()
    w, h = max(options.width // 2, 1), max(options.height // 2, 1)
    views = [(label, dataclasses.replace(options, width=w, height=h, views=False, turntable=0,
                                         yaw=options.yaw if yaw is None else yaw,
                                         pitch=options.pitch if pitch is None else pitch))
             for label, yaw, pitch in VIEWS]
    from PIL import ImageDraw  # with its fonts: only a views sheet draws text
    rgba8 = np.zeros((2 * h, 2 * w, 4), np.uint8)
    plan: dict = {}
    for i, (label, o) in enumerate(views):
        f = render(asset, env, o)  # not kept: a kept frame has its linear image read (render)
        y, x = (i // 2) * h, (i % 2) * w
        im = Image.fromarray(f.rgba8, "RGBA")
        ImageDraw.Draw(im).text((6, 4), label, fill=(40, 40, 40, 255))
        rgba8[y:y + h, x:x + w] = np.asarray(im)
        plan = dict(f.plan)
    plan["views"] = [label for label, _ in views]

    def linear() -> np.ndarray:
        out = np.zeros((2 * h, 2 * w, 4), np.float32)
        for i, (_, o) in enumerate(views):
            y, x = (i // 2) * h, (i % 2) * w
            out[y:y + h, x:x + w] = render(asset, env, o).linear
        return out

    return Frame(linear, rgba8, plan, FrameTimings((time.perf_counter() - t0) * 1e3),
                 alpha_is_mask=alpha_is_mask(options))
