"""Texture paths a city model names, kept within the model's folder.

A CityJSON `appearance.textures[].image` or a CityGML `imageURI` is a path relative to the
model's file. One that leaves its folder (an absolute path, `..` above it, a link inside it
pointing out) is not read: a model from elsewhere must not make geofuse open files it was not
given. Its surfaces are drawn by kind, and the reader says so (`outside_note`).
"""

from __future__ import annotations

from pathlib import Path


def texture_file(model: Path, uri: str) -> Path | None:
    """The image `uri` names beside the model file `model`, None where it lies outside the
    model's folder (links followed, as opening it would)."""
    folder = model.parent.resolve()
    path = model.parent / uri.strip()
    return path if path.resolve().is_relative_to(folder) else None


def outside_note(model: Path, uri: str) -> str:
    """What a reader says of a texture `uri` that leaves the folder of `model`."""
    return (
        f"{model.name}: texture {uri.strip()!r} lies outside the model's folder "
        f"{model.parent}: not read; its surfaces are drawn by kind"
    )
