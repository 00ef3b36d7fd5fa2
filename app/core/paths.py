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
    base = os.environ.get("XDG_CONFIG_HOME")
    if base:
        return Path(base) / APP
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Application Support" / APP
    if os.name == "nt" and os.environ.get("APPDATA"):
        return Path(os.environ["APPDATA"]) / APP
    return Path.home() / ".config" / APP


def cache_dir() -> Path:
    """The user's cache folder: $XDG_CACHE_HOME/geofuse (~/.cache/geofuse); on macOS
    ~/Library/Caches/geofuse, on Windows %LOCALAPPDATA%/geofuse/Cache."""
    base = os.environ.get("XDG_CACHE_HOME")
    if base:
        return Path(base) / APP
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / APP
    if os.name == "nt" and os.environ.get("LOCALAPPDATA"):
        return Path(os.environ["LOCALAPPDATA"]) / APP / "Cache"
    return Path.home() / ".cache" / APP
