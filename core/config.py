"""Configuration machinery: flags, then ASSET_PREVIEW_* variables, then defaults (one declaration
per knob, core.schema's `knob`). The knobs live with what they configure: pipeline/limits.py
(input limits, pipeline), service/settings.py (the service), and the renderer's GPU budget here
(the renderer may import core only).

The variables are read here rather than by pydantic-settings, whose import (asyncio, dotenv,
its CLI and cloud sources) was a fifth of a cold render's own imports; every knob is a scalar
(str, int, float, bool, Path), parsed from the variable's text as pydantic's lax mode parses it
(core.schema checks it, and leaves to pydantic what it does not parse itself, and the errors).
Names match case-insensitively, as pydantic-settings' default."""
from __future__ import annotations

import dataclasses
import os
import typing
from functools import lru_cache
from typing import Any

from core.schema import check, declared, knob

ENV_PREFIX = "ASSET_PREVIEW_"
_Self = typing.TypeVar("_Self", bound="FromEnv")


class FromEnv:
    """Base of frozen `@dataclasses.dataclass(frozen=True, init=False)` settings classes."""
    PYDANTIC_CONFIG: typing.ClassVar[dict] = {"extra": "ignore"}  # unknown names are someone else's

    def __init__(self, **values: Any) -> None:
        """Arguments over ASSET_PREVIEW_<FIELD> variables over defaults (a ValueError, pydantic's
        ValidationError, names a value refused)."""
        given = {**environment_values(type(self)), **values}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]  # subclasses are dataclasses
            object.__setattr__(self, f.name, given.get(f.name, f.default))
        check(self)

    @classmethod
    def from_env(cls: type[_Self], **overrides: Any) -> _Self:
        """Defaults, overridden by ASSET_PREVIEW_<FIELD> variables, overridden by arguments
        (arguments that are None are ignored, so argparse results can be passed as they are)."""
        return cls(**{k: v for k, v in overrides.items() if v is not None})

    @classmethod
    def defaults(cls: type[_Self]) -> _Self:
        """The declared defaults, whatever the environment says."""
        obj = cls.__new__(cls)
        for f in dataclasses.fields(obj):  # type: ignore[arg-type]
            object.__setattr__(obj, f.name, f.default)
        return obj


def environment_values(cls: type) -> dict[str, str]:
    """The ASSET_PREVIEW_<FIELD> variables set for `cls`'s fields, by field name."""
    found = {k.upper(): v for k, v in os.environ.items() if k.upper().startswith(ENV_PREFIX)}
    return {name: found[ENV_PREFIX + name.upper()] for name in declared(cls)
            if ENV_PREFIX + name.upper() in found}


@dataclasses.dataclass(frozen=True, init=False)
class RendererSettings(FromEnv):
    """How much a renderer process keeps uploaded (the service sets its workers' own)."""
    gpu_bytes: int = knob(512 * 2**20, ge=1, description="bytes of meshes and textures a renderer keeps uploaded")
    gpu_environments: int = knob(4, ge=1, description="environments kept uploaded")


@lru_cache(maxsize=1)
def renderer_settings() -> RendererSettings:
    """The environment's renderer settings, read once."""
    return RendererSettings()
