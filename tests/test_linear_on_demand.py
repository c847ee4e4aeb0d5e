"""A frame's linear image is drawn by its final pass only when asked for (a thumbnail never
asks), and it is the same image whenever it is asked for: before or after later frames have
drawn over the render target, and the one the final pass draws with the display image."""
from __future__ import annotations

import dataclasses
import gc

import numpy as np
import pytest

from core.cubemap import default_face_size
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from renderer import render
from renderer.raster import final as R  # the final pass: its draws are spied on


@pytest.fixture(scope="module")
def duck(assets, tmp_path_factory):
    cache = tmp_path_factory.mktemp("linear")
    asset = bake_asset(assets / "gltf/Duck.glb", cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    return asset, env


def _outputs_drawn(monkeypatch) -> list[int]:
    drawn: list[int] = []
    draw = R.FinalPass.draw

    def spy(self, ctx, output):
        drawn.append(output)
        return draw(self, ctx, output)
    monkeypatch.setattr(R.FinalPass, "draw", spy)
    return drawn


LOOKS = [{}, {"background": "transparent"}, {"background": "env"}, {"alpha": "coverage"},
         {"msaa": 0}]


@pytest.mark.parametrize("look", LOOKS, ids=[str(x) for x in LOOKS])
def test_linear_read_late_equals_linear_read_at_once(duck, look):
    """Frame A's linear image asked for after B and C drew into the same target (same size)
    is the one read straight after A."""
    asset, env = duck
    o = dataclasses.replace(RenderOptions(width=96, height=80), **look)
    at_once = render(asset, env, o).linear
    late = render(asset, env, o)
    render(asset, env, dataclasses.replace(o, yaw=o.yaw + 90, background="#ff0000"))
    other = render(asset, env, dataclasses.replace(o, yaw=o.yaw + 180))
    assert np.array_equal(late.linear, at_once)
    assert np.isfinite(at_once).all() and at_once[..., 3].max() == 1.0
    assert not np.array_equal(other.linear, at_once)  # a different image where it was drawn


def test_thumbnail_draws_no_linear_image(duck, monkeypatch):
    asset, env = duck
    o = RenderOptions(width=96, height=80)
    render(asset, env, o)
    gc.collect()
    drawn = _outputs_drawn(monkeypatch)
    for _ in range(3):
        assert render(asset, env, o).rgba8.shape == (80, 96, 4)
    assert drawn == [R.DISPLAY] * 3
    kept = render(asset, env, o)
    render(asset, env, o)  # draws over `kept`'s target: its linear image is read first
    assert drawn[3:] == [R.DISPLAY, R.LINEAR, R.DISPLAY]
    assert kept.linear is kept.linear
    assert drawn[3:] == [R.DISPLAY, R.LINEAR, R.DISPLAY]  # read once


def test_turntable_without_linear_draws_none(duck, monkeypatch):
    from renderer.sequence import encode_animation, render_turntable
    asset, env = duck
    o = RenderOptions(width=48, height=40, turntable=4)
    drawn = _outputs_drawn(monkeypatch)
    frames = render_turntable(asset, env, o, keep_linear=False)
    render(asset, env, RenderOptions(width=48, height=40))
    assert drawn == [R.DISPLAY] * 5
    assert encode_animation(frames, "webp")[:4] == b"RIFF"
    with pytest.raises(RuntimeError, match="display pixels only"):
        _ = frames[0].linear
    kept = render_turntable(asset, env, o)  # the default keeps them: read before each next frame
    assert drawn[5:] == [R.DISPLAY, R.LINEAR] * 3 + [R.DISPLAY]
    assert kept[-1].linear[..., 3].max() == 1.0 and drawn[-1] == R.LINEAR  # the last on demand
    assert all(f.linear[..., 3].max() == 1.0 for f in kept)


def test_linear_on_demand_equals_the_pass_that_draws_both(duck, monkeypatch):
    """The display-only and linear-only programs write what the one program writing both
    outputs (final.frag OUTPUT 3, as the gradient's rows use) writes."""
    asset, env = duck
    both: dict = {}
    draw = R.FinalPass.draw

    def draw_both(self, ctx, output):
        both[output] = _draw_both(self, ctx)
        return draw(self, ctx, output)
    for look in LOOKS[:3]:
        o = dataclasses.replace(RenderOptions(width=96, height=80), **look)
        frame = render(asset, env, o)
        linear, rgba8 = frame.linear, frame.rgba8
        with monkeypatch.context() as m:
            m.setattr(R.FinalPass, "draw", draw_both)
            again = render(asset, env, o)
            assert np.array_equal(again.rgba8, rgba8)
        display, lin = both[R.DISPLAY]
        assert np.array_equal(display, rgba8), look
        assert np.array_equal(lin, linear), look


def _draw_both(final, ctx):
    """`final`'s regions drawn by the program with both outputs into a framebuffer of both
    targets: (rgba8, linear)."""
    w, h = final.options.width, final.options.height
    targets = [ctx.texture((w, h), 4, dtype="f1"), ctx.texture((w, h), 4, dtype="f4")]
    fbo = ctx.framebuffer(targets, final.target.display_fbo.depth_attachment)
    try:
        final.draw_into(ctx, fbo, R.DISPLAY | R.LINEAR)
        a, b = np.empty((h, w, 4), np.uint8), np.empty((h, w, 4), np.float32)
        fbo.read_into(a, components=4, attachment=0)
        fbo.read_into(b, components=4, attachment=1, dtype="f4")
        return a, b
    finally:
        fbo.release()
        for t in targets:
            t.release()
