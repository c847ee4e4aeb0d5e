"""Contact sheet for the MaterialX stages: ours | the asset's own reference | bpy's Storm, one
row per stage, from the images `asset-preview bench usd --keep-images DIR` keeps.
`PYTHONPATH=. python -m bench.mtlx_sheet DIR OUT.png [ASSETS]`."""
import sys
from pathlib import Path

from PIL import Image, ImageDraw

H = 256
# (kept image stem, reference image under ASSETS)
ROWS = [
    ("usd__TextureCoordinateTest__TextureCoordinateTestMaterialX.usda",
     "usd/TextureCoordinateTest/thumbnails/TextureCoordinateTest.png"),
    ("usd-wg__test_assets__MaterialXTest__basic.usda",
     "usd-wg/test_assets/MaterialXTest/screenshots/basic.png"),
    ("usd-wg__test_assets__MaterialXTest__basic_flatten.usda",
     "usd-wg/test_assets/MaterialXTest/screenshots/basic.png"),
    ("usd-wg__test_assets__MaterialXTest__basicTextured_flatten.usda",
     "usd-wg/test_assets/MaterialXTest/screenshots/basicTextured_brasstiled.png"),
]


def _fit(path: Path) -> Image.Image:
    im = Image.open(path).convert("RGB")
    return im.resize((round(im.width * H / im.height), H))


def main(kept: str, out: str, assets: str = "/work/shared/assets") -> None:
    rows = []
    for stem, ref in ROWS:
        ours, storm = Path(kept) / f"{stem}.ours.png", Path(kept) / f"{stem}.storm.png"
        if ours.is_file() and storm.is_file():
            rows.append((stem, [_fit(ours), _fit(Path(assets) / ref), _fit(storm)]))
    sheet = Image.new("RGB", (max(sum(t.width for t in r) for _, r in rows), H * len(rows)),
                      (40, 40, 40))
    for i, (stem, tiles) in enumerate(rows):
        x = 0
        for tile in tiles:
            sheet.paste(tile, (x, i * H))
            x += tile.width
        ImageDraw.Draw(sheet).text((4, i * H + 4), stem.split("__")[-1], fill=(255, 255, 0))
    sheet.save(out)
    print(f"wrote {out}: {len(rows)} rows (ours | reference | bpy Storm)")


if __name__ == "__main__":
    main(*sys.argv[1:])
