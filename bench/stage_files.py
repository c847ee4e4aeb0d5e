"""The probe-stage generators' one folder writer: each named stage text as NAME.usda."""
from __future__ import annotations

from pathlib import Path


def write_usda(folder: Path, stages: dict[str, str]) -> list[Path]:
    """Write each stage text to folder/NAME.usda (the folder made if missing); the paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in stages.items():
        path = folder / f"{name}.usda"
        path.write_text(text)
        paths.append(path)
    return paths
