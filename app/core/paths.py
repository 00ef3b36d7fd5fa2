"""Where geofuse keeps a user's settings and caches: the platform's folders (the XDG base
directories on Linux and other Unix, ~/Library on macOS, %APPDATA% / %LOCALAPPDATA% on
Windows), never the working folder. Pure: reads only the environment."""

from __future__ import annotations

import os
import sys
from pathlib import Path

APP = "geofuse"


def config_dir() -> Path:
    """The user's settings folder: $XDG_CONFIG_HOME/geofuse (~/.config/geofuse); on macOS
    ~/Library/Application Support/geofuse, on Windows %APPDATA%/geofuse (XDG_CONFIG_HOME wins
    everywhere when set, as tests set it)."""
    return _platform_dir("XDG_CONFIG_HOME", ".config", "Application Support", "APPDATA", "")


def cache_dir() -> Path:
    """The user's cache folder: $XDG_CACHE_HOME/geofuse (~/.cache/geofuse); on macOS
    ~/Library/Caches/geofuse, on Windows %LOCALAPPDATA%/geofuse/Cache."""
    return _platform_dir("XDG_CACHE_HOME", ".cache", "Caches", "LOCALAPPDATA", "Cache")


def _platform_dir(xdg: str, home: str, library: str, windows: str, below: str) -> Path:
    """$xdg/geofuse where set; else ~/Library/<library>/geofuse on macOS,
    %<windows>%/geofuse[/<below>] on Windows, ~/<home>/geofuse elsewhere."""
    base = os.environ.get(xdg)
    if base:
        return Path(base) / APP
    if sys.platform == "darwin":
        return Path.home() / "Library" / library / APP
    if os.name == "nt" and os.environ.get(windows):
        return Path(os.environ[windows]) / APP / below
    return Path.home() / home / APP
