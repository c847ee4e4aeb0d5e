"""`asset-preview bench accuracy --quick`: the chart's CSV and PNG, and the metrics under it."""
from __future__ import annotations

import argparse
import csv
import math

import numpy as np
import pytest
from PIL import Image

from bench import accuracy, metrics
from bench.reference import load_reference


def test_metrics_zero_on_the_reference_and_grow_with_the_error():
    ref = metrics.reference_at("glass_sphere_ior1.5", 64)
    same = metrics.errors(ref, ref)
    assert all(v == 0 for v in same.values())
    small = metrics.errors(ref * 1.05, ref)
    large = metrics.errors(ref * 1.5, ref)
    for k in ("flip", "rel_mse", "flip_frame", "rel_mse_frame"):
        assert 0 < small[k] < large[k], k
    # Damage confined to the object shows in the object's figure more than the frame's.
    hurt = ref.copy()
    hurt[ref[..., 3] > 0, :3] *= 0.5
    e = metrics.errors(hurt, ref)
    assert e["flip"] > 2 * e["flip_frame"] and e["rel_mse"] > 2 * e["rel_mse_frame"]
    # NaN in an image is an error, not a NaN figure.
    bad = ref.copy()
    bad[0, 0, 0] = np.nan
    assert all(math.isfinite(v) for v in metrics.errors(bad, ref).values())


def test_reference_at_box_filters_exactly():
    full = load_reference("glass_sphere_ior1.5")  # 256 px
    half = metrics.reference_at("glass_sphere_ior1.5", 128)
    assert half.shape == (128, 128, 4)
    assert np.allclose(half[10, 20], full[20:22, 40:42].mean(axis=(0, 1)), atol=1e-6)
    with pytest.raises(FileNotFoundError, match="cannot make"):
        metrics.reference_at("glass_sphere_ior1.5", 100)


def test_pareto_front_and_gap():
    pts = [(1.0, 0.5), (2.0, 0.2), (3.0, 0.3), (10.0, 0.05), (2.0, 0.2)]
    assert metrics.pareto_front(pts) == [True, True, False, True, True]
    front = [p for p, on in zip(pts, metrics.pareto_front(pts)) if on]
    assert metrics.front_gap((2.0, 0.2), front) == 0.0
    assert metrics.front_gap((2.2, 0.21), front) == pytest.approx(0.1)
    assert metrics.front_gap((3.0, 0.3), front) == pytest.approx(0.5)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("accuracy")
    parser = argparse.ArgumentParser()
    accuracy.configure(parser)
    args = parser.parse_args(["--quick", "--out", str(out), "--cache", str(out / "cache")])
    assert accuracy.run(args) == 0
    with open(out / "accuracy.csv") as f:
        return out, list(csv.DictReader(f))


@pytest.mark.slow
def test_quick_chart_writes_csv_and_png(quick):
    out, rows = quick
    assert set(accuracy.COLUMNS) <= set(rows[0])
    scenes = {r["scene"] for r in rows}
    assert scenes == set(accuracy.QUICK_SCENES)
    for r in rows:
        assert r["size"] == "64"
        for k in ("time_ms", "flip", "rel_mse", "flip_frame", "rel_mse_frame"):
            assert math.isfinite(float(r[k])) and float(r[k]) >= 0, (r["scene"], r["method"], k)
        assert r["on_front"] in ("True", "False")
    by = {(r["scene"], r["method"]): r for r in rows}
    for s in scenes:  # every scene has auto, and its plan says what ran
        assert by[s, "auto"]["plan"]
        assert any(r["on_front"] == "True" for r in rows if r["scene"] == s)
    # Glass: both TIR treatments and the ray tracer at every bounce count.
    glass = "glass_sphere_ior1.5"
    for m in ("single", "wyman/tir=paper", "wyman/tir=reflect", "raytrace-1", "raytrace-8"):
        assert (glass, m) in by
    # Physics the chart must show: two interfaces beat one; more bounces do not hurt.
    assert float(by[glass, "raytrace-2"]["flip"]) < float(by[glass, "raytrace-1"]["flip"])
    assert float(by[glass, "wyman/tir=paper"]["flip"]) < float(by[glass, "single"]["flip"])
    assert float(by[glass, "raytrace-8"]["flip"]) <= float(by[glass, "raytrace-2"]["flip"]) + 1e-3
    # Steel is rough: the paper's prefilter is measured beside GGX.
    assert ("steel_sphere", "auto/prefilter=paper") in by
    # The torus fails raster methods: auto with a budget ray traces it.
    assert "raytrace" in by["glass_torus_ior1.5", "auto+budget"]["plan"]
    img = Image.open(out / "speed_accuracy.png")
    assert img.size[0] > 800 and img.size[1] > 400
    assert np.asarray(img.convert("L")).std() > 10  # drawn, not blank


def test_peer_table_names_dominating_settings(capsys):
    """Per Mitsuba point: the fastest raytrace row at least as accurate in less time, 'none'
    where no row is, and a peer that is its own reference (FLIP ~0) left out of the count."""
    from bench.accuracy import peer_table
    rows = [{"scene": "s", "method": m, "time_ms": t, "flip": e} for m, t, e in [
        ("raytrace-8", 100.0, 0.05), ("raytrace-12/split=roulette/ss=2", 40.0, 0.09),
        ("mitsuba-4spp", 50.0, 0.10), ("mitsuba-16spp", 120.0, 0.06),
        ("mitsuba-64spp", 300.0, 0.03), ("mitsuba-256spp", 900.0, 0.0008)]]
    peer_table(rows)
    out = capsys.readouterr().out
    lines = {ln.split("|")[2].strip(): ln for ln in out.splitlines() if ln.startswith("| s |")}
    assert "raytrace-12/split=roulette/ss=2 | 40 / 0.0900" in lines["4spp"]
    assert "| raytrace-8 | 100 / 0.0500 |" in lines["16spp"]
    assert "none" in lines["64spp"] and "256spp" not in lines
    assert "dominated by a raytrace setting: 2/3" in out and "s 256spp" in out
