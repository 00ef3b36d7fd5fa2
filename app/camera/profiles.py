"""Which lens a camera has: the bundled gyroflow profiles (GoPro and DJI, CC0) chosen by camera
model, image shape and lens mode, and the cameras of videos and stills seen through them.

Pixels (u, v) from the top-left corner, centres at half-integers; positions in the local ENU frame
(metres); heading, pitch, roll in degrees (app.geodesy.rotations).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy.typing as npt

from app.camera.intrinsics import Intrinsics
from app.camera.lens import Lens, enclosing_intrinsics, read_profile
from app.camera.pinhole import Camera
from app.core.constants import DEFAULT_FAR_M, DEFAULT_NEAR_M
from app.geodesy import rotations

PROFILE_DIR = (
    Path(__file__).resolve().parent / "lens_profiles"
)  # GoPro and DJI profiles (CC0, gyroflow)
LENS_MODES = {
    "W": "wide",
    "L": "linear",
    "S": "superview",
    "H": "hyperview",
    "N": "narrow",
    "M": "medium",
    "X": "max",
}


ASPECT_TOLERANCE = 0.02  # a profile fits a video whose width/height is within 2 % of its own

# How the gyroflow database's DJI profiles spell a camera (normalized, 'DJI' dropped), beside the
# camera's own name: the database is written by its users, so one drone has several spellings.
DJI_PROFILE_NAMES = {
    "mavicair": ("mavicair1",),
    "mavicair2": ("air2",),
    "air2s": ("mavicair2s", "mavicair2s4k"),
    "mavicpro": ("mavicpro1",),
    "mini2": ("mini24k30fps",),
    "mini2se": ("mavicmini2se27k",),
    "mini3pro": ("minipro3",),
    "mavic3pro": ("mavic3prohasselblad43",),
    "phantom4pro": ("phantom4prov1", "phantom4prov2"),
    "zenmusex7": ("x7", "zemmusex7"),
    "fpv": ("fpvdrone",),
}


def _norm(text: str) -> str:
    return "".join(ch for ch in text.lower() if ch.isalnum())


def _camera_key(brand: str, model: str) -> str:
    """A camera's name as compared: lower-case letters and digits, the brand's name dropped
    ('GoPro Max' -> 'max', 'DJI Mini 3 Pro' -> 'mini3pro')."""
    key, prefix = _norm(model), _norm(brand)
    return key[len(prefix) :] if key.startswith(prefix) and len(key) > len(prefix) else key


def profile_names(brand: str, model: str) -> set[str]:
    """Every spelling of a camera's name (as _camera_key gives) that a bundled profile may use."""
    key = _camera_key(brand, model)
    return {key, *DJI_PROFILE_NAMES.get(key, ())} if brand == "DJI" else {key}


def choose_profile(
    brand: str, model: str, width: int, height: int, mode: str = ""
) -> tuple[Path, str] | None:
    """The bundled profile that best fits a camera: (path, why) or None. The camera model must
    match (GoPro's GPMF device name, e.g. 'HERO8 Black' or 'GoPro Max'; a DJI aircraft's name,
    e.g. 'Mavic Air 2', see profile_names); then the image's aspect ratio, the lens mode's name
    where known (wide, linear, superview...), profiles calibrated without in-camera
    stabilisation, the closest resolution, then the calibration's RMS error and a known readout
    time decide. Profiles of another aspect ratio (beyond
    ASPECT_TOLERANCE) are never chosen: a 16:9 video cut from a 4:3 sensor has its own field."""
    folder = PROFILE_DIR / brand
    if not folder.is_dir() or not model:
        return None
    want = profile_names(brand, model)
    aspect = width / height
    best: tuple[float, Path, str] | None = None
    for path in sorted(folder.glob("*.json")):
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            cal = d["calib_dimension"]
        except (OSError, ValueError, KeyError):
            continue
        if _camera_key(brand, str(d.get("camera_model", ""))) not in want:
            continue
        if abs(cal["w"] / cal["h"] / aspect - 1.0) > ASPECT_TOLERANCE:
            continue  # another frame shape: how it was cropped from the sensor is not known
        name = path.stem.lower()
        score = 10.0 * abs(cal["w"] / cal["h"] - aspect)
        score += 0.0 if not mode or mode in name.replace(" ", "") else 3.0
        score += 1.0 if "eis" in name and "no-eis" not in name else 0.0
        score += abs(cal["w"] - width) / max(width, 1)
        score += 0.05 * min(
            float(d.get("fisheye_params", {}).get("RMS_error") or 5.0), 5.0
        )  # the better calibration
        score += (
            0.0 if d.get("frame_readout_time") else 0.05
        )  # one that can undo the rolling shutter
        if best is None or score < best[0]:
            best = (
                score,
                path,
                f"{d.get('camera_model')} profile '{path.stem}' for {width}x{height}"
                + (f", {mode} lens mode" if mode else ""),
            )
    return None if best is None else (best[1], best[2])


def lens_for_video(lens: Lens, width: int, height: int, rotation_cw: int) -> Lens:
    """A profile's lens for a video shown width x height after turning it by rotation_cw: scaled
    to the stored size, then turned for display."""
    stored = (height, width) if rotation_cw % 180 else (width, height)
    return lens.scaled(*stored).rotated(rotation_cw // 90)


def video_camera(
    profile: str | Path, width: int, height: int, rotation_cw: int
) -> tuple[Intrinsics, Lens]:
    """(the pinhole the depth pass renders, the lens) of a video shown width x height through a
    profile file."""
    lens = lens_for_video(read_profile(profile), width, height, rotation_cw)
    return enclosing_intrinsics(lens), lens


def still_camera(
    image_size: tuple[int, int],
    position_enu: npt.ArrayLike,
    hpr_deg: tuple[float, float, float],
    fov_deg: float | None = None,
    profile: str | Path | None = None,
    near: float = DEFAULT_NEAR_M,
    far: float = DEFAULT_FAR_M,
) -> Camera:
    """The camera of a still image (width, height px) taken at `position_enu` (m, the local
    frame) with heading, pitch, roll (deg, app.geodesy.rotations): through the lens profile when given
    (the depth pass renders its enclosing pinhole), else a pinhole of horizontal `fov_deg`.
    Raises ValueError for a field of view out of range; DataFormatError for a bad profile."""
    width, height = image_size
    lens = None
    if profile is not None:
        lens = read_profile(profile).scaled(width, height)
        intr = enclosing_intrinsics(lens)
    elif fov_deg is not None:
        intr = Intrinsics.from_fov(width, height, fov_deg)
    else:
        raise ValueError("a still needs a field of view or a lens profile")
    return Camera.create(
        intr,
        position_enu,
        rotations.camera_quat_from_hpr(*hpr_deg),
        near=near,
        far=far,
        lens=lens,
    )
