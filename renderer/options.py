"""Everything a render request can set. The service, the CLI and the bench build these."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

Method = Literal["auto", "opaque", "single", "wyman", "raytrace"]
Tonemap = Literal["neutral", "aces", "none"]


@dataclass(frozen=True)
class MaterialOverride:
    """Per-request material applied to every mesh ("preview any mesh as glass or steel").
    None leaves the asset's own value."""
    base_color: tuple[float, float, float] | None = None  # linear RGB
    metallic: float | None = None
    roughness: float | None = None
    ior: float | None = None
    transmission: float | None = None

    def is_empty(self) -> bool:
        return all(v is None for v in asdict(self).values())


@dataclass(frozen=True)
class RenderOptions:
    width: int = 512
    height: int = 512
    yaw: float = 0.0          # degrees, see renderer.camera
    pitch: float = 0.0
    fov: float = 40.0         # vertical, degrees
    distance: float | None = None  # None: auto-frame
    method: Method = "auto"
    tonemap: Tonemap = "neutral"
    exposure: float = 0.0     # stops (EV): linear radiance is scaled by 2**exposure before tone mapping
    background: str = "env"   # "env" | "transparent" | "#rrggbb"
    background_blur: float = 0.0  # 0..1, roughness of the prefiltered mip shown behind the asset
    override: MaterialOverride | None = None
    msaa: int = 4
    lights: bool = True       # the asset's KHR_lights_punctual lights
    multiscatter: bool = False  # energy compensation for rough metals
    tir: Literal["paper", "reflect"] | None = None  # wyman TIR treatment; None = default
    bounces: int = 8          # raytrace
    debug: Literal["backface_normals", "tir", "exit_distance"] | None = None
    time_budget_ms: float | None = None  # lets `auto` pick raytrace where it pays
