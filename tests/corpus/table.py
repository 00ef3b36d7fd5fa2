"""Every damaged-input case and what geofuse must do with it.

Columns: the case's name; the generator in generate.py that damages it; the command line
({d} = the case's folder, {s} = its phone session's manifest, {shared} = ../shared/data); the
outcome ("ok": exit 0, "error": exit 2 with one line, "nothing drawn": a still written that shows
none of the scene, said, exit 1); and `says`: for an error, what the one line
must name (the file, key or option at fault); for "ok", a warning that must be printed because
data were dropped or repaired ("" when nothing was dropped). Every case also asserts: no traceback,
no input file changed, no NaN in any output.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Case:
    name: str
    make: str
    argv: tuple[str, ...]
    outcome: str
    says: str
    shared: bool = False  # needs ../shared/data


SOLVE = ("solve", "{s}", "--source", "gd-ahrs", "--out", "{d}/poses.csv")
RENDER_SESSION = (
    "render",
    "--session",
    "{s}",
    "--time",
    "2",
    "--size",
    "160x90",
    "--out",
    "{d}/frame.png",
)
RENDER = ("render", "--scene", "{d}/session/scene.obj", "--origin", "34.8,113.53,110", "--image", "{d}/photo.jpg",
          "--pose", "34.8,113.53,111.6,0,-10,0", "--fov", "60", "--size", "160x90", "--out", "{d}/still.png")  # fmt: skip


def _with(argv: tuple[str, ...], option: str, value: str) -> tuple[str, ...]:
    a = list(argv)
    a[a.index(option) + 1] = value
    return tuple(a)


CASES = (
    # sensor logs
    Case("acc all zeros", "zero_accelerometer", SOLVE, "error", "acc.csv"),
    Case(
        "mag all zeros",
        "zero_magnetometer",
        _with(SOLVE, "--source", "gd-imu"),
        "ok",
        "the magnetometer reads",
    ),
    Case("gyro times in ns labelled s", "gyro_times_in_ns", SOLVE, "error", "gyr.csv"),
    Case("acc NaN rows", "acc_with_nan_rows", SOLVE, "ok", "NaN"),
    Case("acc without z", "acc_without_z", SOLVE, "error", "acc.csv"),
    Case("gyro time backwards", "gyro_time_backwards", SOLVE, "ok", "backwards"),
    # GNSS
    Case("gnss 0N 0E before lock", "gnss_null_island_first", SOLVE, "ok", "0 N 0 E"),
    Case("gnss jump", "gnss_with_a_jump", SOLVE, "ok", "jumps"),
    Case("gnss latitude out of range", "gnss_out_of_range", SOLVE, "error", "gnss.csv"),
    Case("gnss without h", "gnss_missing_column", SOLVE, "error", "gnss.csv"),
    # manifests
    Case("mount height nan", "manifest_nan_mount_height", SOLVE, "error", "gnss.mount_height_m"),
    Case("height offset nan", "manifest_nan_height_offset", SOLVE, "error", "gnss.height_offset_m"),
    Case("scene scale 0", "manifest_zero_scale", SOLVE, "error", "scene.scale"),
    Case("scene heading inf", "manifest_infinite_heading", SOLVE, "error", "scene.heading_deg"),
    Case("video missing", "manifest_missing_video", SOLVE, "error", "video.path"),
    Case("manifest not TOML", "manifest_not_toml", SOLVE, "error", "session.toml"),
    Case("origin latitude 95", "manifest_origin_out_of_range", SOLVE, "error", "origin"),
    # scenes
    Case("scene without faces", "scene_without_faces", SOLVE, "error", "scene.obj"),
    Case("scene truncated glb", "scene_truncated_glb", SOLVE, "error", "scene.glb"),
    Case("scene 111 km away", "scene_far_away", SOLVE, "ok", "km from the camera's track"),
    Case(
        "render --session, scene far",
        "scene_far_away",
        RENDER_SESSION,
        "nothing drawn",
        "km from the camera's track",
    ),
    Case("scene a 3D Tiles tileset", "tileset_scene", RENDER_SESSION, "ok", "3D Tiles 1.0"),
    Case("tileset 5 km away", "tileset_far_away", SOLVE, "ok", "4.8 km from the camera's track"),
    Case("tileset without root", "tileset_without_root", SOLVE, "error", "tileset.json"),
    Case(
        "render a still on a tileset, no --origin",
        "tileset_and_photo",
        ("render", "--scene", "{d}/session/tileset.json", *RENDER[5:]),
        "ok",
        "3D Tiles 1.0",
    ),
    Case("DEM with nodata holes", "dem_with_holes", SOLVE, "ok", "nodata"),
    Case("DEM 55 km away", "dem_far_away", SOLVE, "error", "dem.tif"),
    Case("DEM not a GeoTIFF", "dem_not_a_geotiff", SOLVE, "error", "dem.tif"),
    Case("DEM vertical datum unknown", "dem_vertical_unknown", SOLVE, "error", "dem.vertical"),
    Case(
        "--scene with a manifest",
        "nothing",
        (*SOLVE[:2], "--scene", "{d}/session/scene.obj", *SOLVE[2:]),
        "error",
        "--scene/--dem/--buildings goes with a clip",
    ),
    # video
    Case("video not a video", "video_not_a_video", SOLVE, "error", "clip.mp4"),
    Case("video cut short, index first", "video_cut_short_index_first", SOLVE, "ok", "cut short"),
    # outputs
    Case(
        "solve onto the scene",
        "nothing",
        _with(SOLVE, "--out", "{d}/session/scene.obj"),
        "error",
        "--out",
    ),
    Case(
        "solve onto the truth",
        "nothing",
        _with(SOLVE, "--out", "{d}/session/truth.csv"),
        "error",
        "--out",
    ),
    Case("solve into a folder", "nothing", _with(SOLVE, "--out", "{d}/session"), "error", "--out"),
    Case(
        "solve under a file",
        "nothing",
        _with(SOLVE, "--out", "{d}/session/acc.csv/poses.csv"),
        "error",
        "--out",
    ),
    Case("solve to .txt", "nothing", _with(SOLVE, "--out", "{d}/poses.txt"), "error", "--out"),
    Case(
        "render onto its image",
        "photo_copy",
        _with(RENDER, "--out", "{d}/photo.jpg"),
        "error",
        "--out",
    ),
    Case("render clean", "photo_copy", RENDER, "ok", ""),
    Case(
        "export footprints onto the manifest",
        "nothing",
        ("export", "footprints", "{s}", "--out", "{d}/session/session.toml"),
        "error",
        "--out",
    ),
    Case(
        "export klv to an .mp4",
        "nothing",
        ("export", "klv", "{s}", "--out", "{d}/k.mp4"),
        "error",
        "--out",
    ),
    Case(
        "export footprints clean",
        "nothing",
        ("export", "footprints", "{s}", "--out", "{d}/fp.geojson", "--every", "30"),
        "ok",
        "",
    ),
    # option values
    Case(
        "render --origin 95", "photo_copy", _with(RENDER, "--origin", "95,0,0"), "error", "--origin"
    ),
    Case(
        "render --pose nan",
        "photo_copy",
        _with(RENDER, "--pose", "nan,113.53,111,0,0,0"),
        "error",
        "--pose",
    ),
    Case("render --far 0", "photo_copy", (*RENDER, "--far", "0"), "error", "--far"),
    Case(
        "render --size too large",
        "photo_copy",
        _with(RENDER, "--size", "20000x100"),
        "error",
        "--size",
    ),
    Case("render --time nan", "nothing", _with(RENDER_SESSION, "--time", "nan"), "error", "--time"),
    Case(
        "render --time past the end",
        "nothing",
        _with(RENDER_SESSION, "--time", "1000"),
        "error",
        "--time",
    ),
    Case(
        "solve unknown source", "nothing", _with(SOLVE, "--source", "kalman"), "error", "--source"
    ),
    # DJI subtitles
    Case(
        "srt heights 1e38",
        "srt_heights_absurd",
        ("telemetry", "{d}/clip.srt", "--csv", "{d}/track.csv"),
        "ok",
        "impossible heights",
        True,
    ),
    Case(
        "srt dated layout",
        "srt_dated_layout",
        ("telemetry", "{d}/clip.srt", "--csv", "{d}/track.csv"),
        "ok",
        "",
        True,
    ),
    Case(
        "srt blank line inside entries",
        "srt_blank_line_inside",
        ("telemetry", "{d}/clip.srt", "--csv", "{d}/track.csv"),
        "ok",
        "",
        True,
    ),
    Case(
        "manifest with a subtitle without gimbal",
        "srt_without_gimbal_in_manifest",
        ("solve", "{d}/drone/session.toml", "--out", "{d}/poses.csv"),
        "ok",
        "",
        True,
    ),
    # GPX
    Case(
        "gpx non-numeric ele and speed",
        "gpx_bad_numbers",
        ("telemetry", "{d}/track.gpx", "--csv", "{d}/track.csv"),
        "ok",
        "unparsable <ele>",
        True,
    ),
    Case(
        "gpx latitude 95",
        "gpx_latitude_95",
        ("telemetry", "{d}/track.gpx"),
        "error",
        "track.gpx",
        True,
    ),
    # GoPro
    Case(
        "gopro unknown ORIN letter",
        "gopro_unknown_orin",
        ("telemetry", "{d}/gopro.mp4"),
        "error",
        "ORIN",
        True,
    ),
    Case(
        "gopro clip on a DEM",
        "dem_under_gopro_clip",
        (
            "solve",
            "{shared}/real/gopro/max-heromode.mp4",
            "--dem",
            "{d}/dem.tif",
            "--out",
            "{d}/poses.csv",
        ),
        "ok",
        "terrain of",
        True,
    ),
    Case(
        "gopro all-zero CORI",
        "gopro_zero_cori",
        ("solve", "{d}/gopro.mp4", "--out", "{d}/poses.csv"),
        "ok",
        "CORI",
        True,
    ),
    Case(
        "gopro all-zero ACCL",
        "gopro_zero_accl",
        ("telemetry", "{d}/gopro.mp4"),
        "error",
        "gopro.mp4",
        True,
    ),
    Case("raw GPMF payload", "gopro_raw_payload", ("telemetry", "{d}/hero6.gpmd"), "ok", "", True),
    # viewer script (parsed without a window)
    Case(
        "script not UTF-8",
        "script_not_utf8",
        ("view", "--script", "{d}/script.txt"),
        "error",
        "script.txt",
    ),
)
