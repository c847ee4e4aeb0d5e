"""Seed an empty store with the sample assets, so a fresh server shows thumbnails.

Uses the two samples shipped in `service/samples/`, or the folder `--samples` names. Folders of files (a .gltf with its .bin, a USD with its layers)
go in as zip archives, through the same path as any upload.
"""
from __future__ import annotations

import io
import logging
import zipfile
from pathlib import Path

log = logging.getLogger(__name__)

PACKAGED = Path(__file__).resolve().parent / "samples"


def default_folder() -> Path:
    return PACKAGED


def sample_uploads(folder: Path) -> list[tuple[str, bytes, str | None]]:
    """(file name, bytes, main file inside an archive) for every sample, smallest first.
    `folder` is laid out like tests/assets (gltf/, mesh/, usd/) or holds plain files."""
    out: list[tuple[str, bytes, str | None]] = []
    shared = Path(folder)
    if (shared / "gltf").is_dir():
        for sub, patterns in (("gltf", ("*.glb",)), ("mesh", ("*.ply", "*.stl", "*.STL")),
                              ("usd", ("*.usda",))):
            for pattern in patterns:
                out += [(p.name, p.read_bytes(), None) for p in sorted((shared / sub).glob(pattern))]
        gltf = shared / "gltf"
        if (gltf / "rgb_cube_with_primitives.gltf").is_file():
            out.append(("rgb_cube_with_primitives.gltf",
                        (gltf / "rgb_cube_with_primitives.gltf").read_bytes(), None))
        if (gltf / "TestScene.gltf").is_file():
            out.append(("TestScene.zip", _zip(gltf, ["TestScene.gltf", "TestScene.bin"]), "TestScene.gltf"))
        for sample, main in (("TextureCoordinateTest", "TextureCoordinateTest.usda"), ("Teapot", "Teapot.usd")):
            d = shared / "usd" / sample
            if (d / main).is_file():
                files = [p.relative_to(d).as_posix() for p in sorted(d.rglob("*"))
                         if p.is_file() and p.suffix.lower() in (".usd", ".usda", ".usdc", ".png", ".jpg")
                         and "thumbnails" not in p.parts and "cards" not in p.parts]
                out.append((f"{sample}.zip", _zip(d, files), main))
    else:
        out += [(p.name, p.read_bytes(), None) for p in sorted(shared.iterdir())
                if p.suffix.lower() in (".glb", ".gltf", ".usda", ".usdc", ".usdz", ".ply", ".stl", ".obj")]
    return sorted(out, key=lambda item: len(item[1]))


def _zip(folder: Path, names: list[str]) -> bytes:
    """A deterministic archive (fixed timestamps), so the same files give the same asset id."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in names:
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = 0o100644 << 16
            zf.writestr(info, (folder / name).read_bytes(), zipfile.ZIP_DEFLATED)
    return buf.getvalue()


async def seed(service) -> None:
    """Upload every sample (each failure logged, not fatal), then mark the store seeded."""
    from core.errors import AssetError
    from service.store import write_atomic
    from service.workers.pool import WorkerFailure

    async def chunks(data: bytes):
        yield data

    folder = service.settings.samples or default_folder()
    for name, data, main in sample_uploads(folder):
        try:
            rec, created = await service.add_asset(name, chunks(data), main)
            log.info("seeded %s as %s", name, rec.id)
        except (AssetError, WorkerFailure) as exc:
            log.warning("sample %s not seeded: %s", name, exc)
    write_atomic(service.store.root / "seeded", b"")
