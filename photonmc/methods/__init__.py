"""Rendering methods by CLI name."""
from __future__ import annotations

from ..errors import SettingsError
from .base import Method, MethodSettings

# The methods photonmc offers, by CLI name.
PLANNED = ("pt", "sppm", "visibility", "spatial-tf", "vcm", "mbe")


def method_class(name: str):
    if name == "pt":
        from .pt import PathTracer
        return PathTracer
    if name == "sppm":
        from .sppm import Sppm
        return Sppm
    if name == "visibility":
        from .guided import Visibility
        return Visibility
    if name == "spatial-tf":
        from .guided import SpatialTarget
        return SpatialTarget
    if name == "vcm":
        from .vcm import Vcm
        return Vcm
    if name == "mbe":
        from .mbe import Mbe
        return Mbe
    raise SettingsError(f"unknown method '{name}' (choose from {', '.join(PLANNED)})")


def create(name: str, dscene, settings: MethodSettings) -> Method:
    return method_class(name)(dscene, settings)


__all__ = ["PLANNED", "Method", "MethodSettings", "create", "method_class"]
