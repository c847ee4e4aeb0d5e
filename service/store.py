"""Uploaded assets and environments on disk, and finished thumbnails.

Layout under `<cache>/service/`:
    assets/<id>/record.json      what GET /assets/{id} answers (status, summary, bake key)
    assets/<id>/src/...          the uploaded file, or the archive's extracted files
    environments/<id>/record.json, environments/<id>/<file>
    thumbs/<id>/<key>.<fmt>      finished thumbnails
    tmp/                         staging; everything appears elsewhere only by rename

An asset folder is built in tmp/ and renamed into place, and every file is written to a
temporary name and then `os.replace`d, so a killed server never leaves a half-written file
where it would be read. The id is the SHA-256 of the uploaded bytes, so the same upload twice
is the same asset.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import time
import uuid
from pathlib import Path

from pydantic import BaseModel

from service.records import AssetRecord, EnvironmentRecord

log = logging.getLogger(__name__)

ID_CHARS = 32  # hex digits of the SHA-256 kept as the id (128 bits)
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def content_id(digest: "hashlib._Hash") -> str:
    return digest.hexdigest()[:ID_CHARS]


def safe_name(filename: str, default: str = "upload") -> str:
    """A file name that is only a name: no folders, no odd characters, not hidden."""
    base = filename.replace("\\", "/").rsplit("/", 1)[-1]
    base = _UNSAFE.sub("_", base).lstrip("._")
    return base[:120] or default


def write_atomic(path: Path, data: bytes) -> None:
    """Write `data` to `path` so that readers see the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_record(path: Path, rec: BaseModel) -> None:
    write_atomic(path, json.dumps(rec.model_dump(), indent=1, sort_keys=True).encode())


class Store:
    """Records of assets and environments, mirrored in memory, authoritative on disk."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.assets_dir = self.root / "assets"
        self.envs_dir = self.root / "environments"
        self.thumbs_dir = self.root / "thumbs"
        self.tmp_dir = self.root / "tmp"
        for d in (self.assets_dir, self.envs_dir, self.thumbs_dir, self.tmp_dir):
            d.mkdir(parents=True, exist_ok=True)
        self.assets: dict[str, AssetRecord] = {}
        self.environments: dict[str, EnvironmentRecord] = {}
        self._clean_tmp()
        self._load()

    # -- start-up ---------------------------------------------------------------------------

    def _clean_tmp(self) -> None:
        """Staging left by a killed server is garbage: nothing outside tmp/ points into it."""
        for p in self.tmp_dir.iterdir():
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)

    def _load(self) -> None:
        sources: tuple[tuple[str, Path, dict, type[BaseModel]], ...] = (
            ("asset", self.assets_dir, self.assets, AssetRecord),
            ("environment", self.envs_dir, self.environments, EnvironmentRecord))
        for kind, folder, table, model in sources:
            for d in sorted(folder.iterdir()):
                try:
                    rec = model.model_validate_json((d / "record.json").read_bytes())
                except (OSError, ValueError) as exc:  # pydantic's ValidationError is a ValueError
                    log.warning("ignoring %s folder %s: unreadable record (%s)", kind, d, exc)
                    continue
                table[rec.id] = rec  # type: ignore[attr-defined]
        log.info("store %s: %d assets, %d environments", self.root, len(self.assets),
                 len(self.environments))

    # -- staging ----------------------------------------------------------------------------

    def staging(self) -> Path:
        path = self.tmp_dir / uuid.uuid4().hex
        path.mkdir()
        return path

    # -- assets -----------------------------------------------------------------------------

    def asset_dir(self, asset_id: str) -> Path:
        return self.assets_dir / asset_id

    def asset_path(self, rec: AssetRecord) -> Path:
        return self.asset_dir(rec.id) / "src" / rec.root

    def commit_asset(self, staged: Path, rec: AssetRecord) -> AssetRecord:
        """Move a staged folder (holding `src/`) into place with its record. If the same id
        landed meanwhile (two identical uploads at once), the first one wins."""
        write_record(staged / "record.json", rec)
        target = self.asset_dir(rec.id)
        try:
            os.rename(staged, target)
        except OSError:
            shutil.rmtree(staged, ignore_errors=True)
            if rec.id in self.assets:
                return self.assets[rec.id]
            raise
        self.assets[rec.id] = rec
        return rec

    def update_asset(self, asset_id: str, **fields) -> AssetRecord:
        rec = self.assets[asset_id].model_copy(update=dict(fields, updated=time.time()))
        write_record(self.asset_dir(asset_id) / "record.json", rec)
        self.assets[asset_id] = rec
        return rec

    def delete_asset(self, asset_id: str) -> None:
        """Rename away first so the asset disappears at once, then remove at leisure."""
        self.assets.pop(asset_id, None)
        for folder in (self.asset_dir(asset_id), self.thumbs_dir / asset_id):
            if folder.exists():
                grave = self.tmp_dir / f"deleted-{uuid.uuid4().hex}"
                os.rename(folder, grave)
                shutil.rmtree(grave, ignore_errors=True)

    # -- environments -----------------------------------------------------------------------

    def env_path(self, rec: EnvironmentRecord) -> Path:
        return self.envs_dir / rec.id / rec.file

    def commit_environment(self, staged: Path, rec: EnvironmentRecord) -> EnvironmentRecord:
        write_record(staged / "record.json", rec)
        try:
            os.rename(staged, self.envs_dir / rec.id)
        except OSError:
            shutil.rmtree(staged, ignore_errors=True)
            if rec.id in self.environments:
                return self.environments[rec.id]
            raise
        self.environments[rec.id] = rec
        return rec

    def find_environment(self, name_or_id: str) -> EnvironmentRecord | None:
        rec = self.environments.get(name_or_id)
        if rec is None:
            rec = next((r for r in self.environments.values() if r.name == name_or_id), None)
        return rec
