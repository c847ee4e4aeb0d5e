"""Configuration machinery: flags, then ASSET_PREVIEW_* variables, then defaults (one pydantic
declaration per knob). The knobs live with what they configure: pipeline/limits.py (input
limits, pipeline), service/settings.py (the service), and the renderer's GPU budget here (the
renderer may import core only).

The variables are read here rather than by pydantic-settings, whose import (asyncio, dotenv,
its CLI and cloud sources) was a fifth of a cold render's own imports; every knob is a scalar
(str, int, float, bool, Path), which pydantic's lax mode parses from the variable's text as
pydantic-settings did. Names match case-insensitively, as pydantic-settings' default."""
from __future__ import annotations

import os
from functools import lru_cache

from pydantic import BaseModel, ConfigDict, Field

ENV_PREFIX = "ASSET_PREVIEW_"


class FromEnv(BaseModel):
    model_config = ConfigDict(frozen=True, extra="ignore")

    def __init__(self, **values) -> None:
        """Arguments over ASSET_PREVIEW_<FIELD> variables over defaults."""
        super().__init__(**{**environment_values(type(self)), **values})

    @classmethod
    def from_env(cls, **overrides):
        """Defaults, overridden by ASSET_PREVIEW_<FIELD> variables, overridden by arguments
        (arguments that are None are ignored, so argparse results can be passed as they are)."""
        return cls(**{k: v for k, v in overrides.items() if v is not None})


def environment_values(cls: type[BaseModel]) -> dict[str, str]:
    """The ASSET_PREVIEW_<FIELD> variables set for `cls`'s fields, by field name."""
    found = {k.upper(): v for k, v in os.environ.items() if k.upper().startswith(ENV_PREFIX)}
    return {name: found[ENV_PREFIX + name.upper()] for name in cls.model_fields
            if ENV_PREFIX + name.upper() in found}


class RendererSettings(FromEnv):
    """How much a renderer process keeps uploaded (the service sets its workers' own)."""
    gpu_bytes: int = Field(512 * 2**20, ge=1, description="bytes of meshes and textures a renderer keeps uploaded")
    gpu_environments: int = Field(4, ge=1, description="environments kept uploaded")


@lru_cache(maxsize=1)
def renderer_settings() -> RendererSettings:
    """The environment's renderer settings, read once."""
    return RendererSettings()
