"""What `geofuse sync --write` keeps beside a manifest or clip (never in an input), and reading it
back for a manifest's time_offset_s = "auto"."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from app.core.errors import GeofuseError
from app.sync.fit import SyncResult


def settings_path(source: Path) -> Path:
    """The session's own file of settings beside its manifest or clip (never an input):
    `NAME.geofuse.toml`, holding what `geofuse sync --write` found."""
    return source.with_name(source.stem + ".geofuse.toml")


def read_settings(source: Path) -> dict:
    """The settings file's tables ({} when there is none); a broken one is an error naming it."""
    path = settings_path(source)
    if not path.is_file():
        return {}
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GeofuseError(
            f"{path}: not valid TOML ({exc}); delete it or run geofuse sync --write again"
        ) from exc


def synced_offset(source: Path) -> float | None:
    """The offset stored by `geofuse sync --write` for this manifest or clip, or None."""
    value = read_settings(source).get("sync", {}).get("time_offset_s")
    return float(value) if isinstance(value, (int, float)) and np.isfinite(value) else None


def synced_drift(source: Path) -> tuple[float, float]:
    """(drift ppm, pivot session time) stored beside the offset, or (0, 0)."""
    sync = read_settings(source).get("sync", {})
    drift, pivot = sync.get("drift_ppm", 0.0), sync.get("drift_pivot_s", 0.0)
    ok = all(isinstance(x, (int, float)) and np.isfinite(x) for x in (drift, pivot))
    return (float(drift), float(pivot)) if ok else (0.0, 0.0)


def settings_text(result: SyncResult, total_offset_s: float) -> str:
    return (
        "# written by `geofuse sync --write`: the session's own settings (its inputs are never written)\n"
        f"[sync]\ntime_offset_s = {total_offset_s:.6f}   # seconds added to the video's times\n"
        f"drift_ppm = {result.drift_ppm:.2f}   # the video clock's rate error (fitted on long clips; 0 otherwise)\n"
        f"drift_pivot_s = {result.reference_s:.6f}   # session time at which the offset holds exactly\n"
        f"confidence = {result.confidence:.4f}\nwindows = {len(result.windows)}\n"
    )
