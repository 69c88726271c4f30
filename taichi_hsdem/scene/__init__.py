"""Scene: the typed, validated, immutable description of one run, read from TOML.

:mod:`.keys` declares every key (kind, unit, range, documentation),
:mod:`.load` validates a TOML table or dict against them, and :mod:`.toml` reads
and writes the files.
"""
from .keys import (
                   AUTO,
                   ClogConfig,
                   ContactConfig,
                   DampingConfig,
                   FeedConfig,
                   FluidConfig,
                   GeometryConfig,
                   OutputConfig,
                   RunConfig,
                   SceneError,
                   SpeciesConfig,
)
from .load import Scene, load_scene
from .toml import read_toml, scene_to_toml

__all__ = ["AUTO", "ClogConfig", "ContactConfig", "DampingConfig", "FeedConfig", "FluidConfig",
           "GeometryConfig", "OutputConfig", "RunConfig", "Scene", "SceneError",
           "SpeciesConfig", "load_scene", "read_toml", "scene_to_toml"]
