"""Write the damaged-input corpus into a folder: a small simulated phone session (app.simulate.phone)
and copies of the shared real files, each case damaged in one way. Nothing here is stored in the
repository; every file is made from the sample generator or ../shared/data at test time.

Each `make_*` function takes the case's folder (a fresh copy of the phone session lives in
`session/`) and returns nothing; table.py names the function of each case.
"""

from __future__ import annotations

import re
import shutil
import struct
from pathlib import Path

import numpy as np

PHONE_SECONDS = 6.0


def phone_session(dest: Path) -> Path:
    """The clean phone session (6 s, 100 Hz IMU, 1 Hz GNSS with velocities, a flat scene)."""
    from app.simulate.phone import walking_pan, write_session

    return write_session(dest, walking_pan(), duration_s=PHONE_SECONDS)


def copy_session(clean: Path, dest: Path) -> Path:
    shutil.copytree(clean, dest)
    return dest / "session.toml"


# --- helpers -------------------------------------------------------------------------------------


def rewrite_csv(path: Path, edit) -> None:
    """Apply edit(header, rows) -> (header, rows) to a CSV file (rows: lists of strings)."""
    lines = path.read_text().splitlines()
    header, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    header, rows = edit(header, rows)
    path.write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")


def set_manifest(manifest: Path, section: str, key: str, value: str) -> None:
    """Set `key = value` (TOML text) in [section], adding the key if absent."""
    text = manifest.read_text()
    pattern = re.compile(
        rf"(\[{re.escape(section)}\][^\[]*?)^{re.escape(key)}\s*=[^\n]*$", re.M | re.S
    )
    if pattern.search(text):
        text = pattern.sub(lambda m: f"{m.group(1)}{key} = {value}", text, count=1)
    else:
        text = text.replace(f"[{section}]\n", f"[{section}]\n{key} = {value}\n", 1)
    manifest.write_text(text)


def zero_gpmf_key(data: bytearray, key: bytes) -> int:
    """Zero the sample data of every `key` KLV in a GPMF byte stream; returns how many."""
    n = 0
    for m in re.finditer(re.escape(key), bytes(data)):
        i = m.start()
        if i + 8 > len(data):
            continue
        size, repeat = data[i + 5], struct.unpack(">H", data[i + 6 : i + 8])[0]
        length = size * repeat
        if data[i + 4 : i + 5] != b"\x00" and 0 < length < 1_000_000:
            data[i + 8 : i + 8 + length] = bytes(length)
            n += 1
    return n


# --- the damage ----------------------------------------------------------------------------------


def zero_accelerometer(d: Path) -> None:
    rewrite_csv(d / "session/acc.csv", lambda h, rows: (h, [[r[0], "0", "0", "0"] for r in rows]))


def zero_magnetometer(d: Path) -> None:
    rewrite_csv(d / "session/mag.csv", lambda h, rows: (h, [[r[0], "0", "0", "0"] for r in rows]))


def gyro_times_in_ns(d: Path) -> None:
    rewrite_csv(
        d / "session/gyr.csv",
        lambda h, rows: (h, [[f"{float(r[0]) * 1e9:.0f}", *r[1:]] for r in rows]),
    )


def acc_with_nan_rows(d: Path) -> None:
    rewrite_csv(
        d / "session/acc.csv",
        lambda h, rows: (
            h,
            [r if i % 50 else [r[0], "nan", r[2], r[3]] for i, r in enumerate(rows)],
        ),
    )


def acc_without_z(d: Path) -> None:
    rewrite_csv(d / "session/acc.csv", lambda h, rows: (h[:3], [r[:3] for r in rows]))


def gyro_time_backwards(d: Path) -> None:
    def edit(h, rows):
        rows[100][0], rows[101][0] = rows[101][0], rows[100][0]
        return h, rows

    rewrite_csv(d / "session/gyr.csv", edit)


def gnss_null_island_first(d: Path) -> None:
    def edit(h, rows):
        first = [str(float(rows[0][0]) - 1.0), "0", "0", "0", "0", "0", "0"]
        return h, [first] + rows

    rewrite_csv(d / "session/gnss.csv", edit)


def gnss_with_a_jump(d: Path) -> None:
    rewrite_csv(
        d / "session/gnss.csv",
        lambda h, rows: (
            h,
            [r if i != 3 else [r[0], str(float(r[1]) + 0.05), *r[2:]] for i, r in enumerate(rows)],
        ),
    )


def gnss_out_of_range(d: Path) -> None:
    rewrite_csv(
        d / "session/gnss.csv",
        lambda h, rows: (h, [[r[0], str(float(r[1]) + 100.0), *r[2:]] for r in rows]),
    )


def gnss_missing_column(d: Path) -> None:
    rewrite_csv(
        d / "session/gnss.csv", lambda h, rows: (h[:3] + h[4:], [r[:3] + r[4:] for r in rows])
    )


def manifest_nan_mount_height(d: Path) -> None:
    set_manifest(d / "session/session.toml", "gnss", "mount_height_m", "nan")


def manifest_nan_height_offset(d: Path) -> None:
    set_manifest(d / "session/session.toml", "gnss", "height_offset_m", "nan")


def manifest_zero_scale(d: Path) -> None:
    set_manifest(d / "session/session.toml", "scene", "scale", "0.0")


def manifest_infinite_heading(d: Path) -> None:
    set_manifest(d / "session/session.toml", "scene", "heading_deg", "inf")


def manifest_missing_video(d: Path) -> None:
    set_manifest(d / "session/session.toml", "video", "path", '"nowhere.mp4"')


def manifest_not_toml(d: Path) -> None:
    (d / "session/session.toml").write_text("[scene\npath = ")


def manifest_origin_out_of_range(d: Path) -> None:
    set_manifest(d / "session/session.toml", "origin", "lat", "95.0")


def scene_without_faces(d: Path) -> None:
    (d / "session/scene.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")


def scene_truncated_glb(d: Path) -> None:
    from app.simulate.sample import SAMPLE_SCENE

    data = SAMPLE_SCENE.read_bytes()
    (d / "session/scene.glb").write_bytes(data[: len(data) // 3])
    set_manifest(d / "session/session.toml", "scene", "path", '"scene.glb"')


def scene_far_away(d: Path) -> None:
    set_manifest(d / "session/session.toml", "scene", "origin", "[35.8, 113.53, 110.0]")


def video_not_a_video(d: Path) -> None:
    (d / "session/clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 but nothing after that")


def video_cut_short_index_first(d: Path) -> None:
    """The clip remuxed with its index (moov) at the front, then cut in half."""
    import av

    src, fast = d / "session/clip.mp4", d / "fast.mp4"
    with av.open(str(src)) as i, av.open(str(fast), "w", options={"movflags": "faststart"}) as o:
        s = o.add_stream_from_template(i.streams.video[0])
        for p in i.demux(i.streams.video[0]):
            if p.dts is not None:
                p.stream = s
                o.mux(p)
    data = fast.read_bytes()
    src.write_bytes(data[: int(len(data) * 0.6)])
    fast.unlink()


def srt_heights_absurd(d: Path, shared: Path) -> None:
    text = (shared / "real/dji/p4_rtk.SRT").read_text(encoding="utf-8")
    count = iter(range(10_000))
    text = re.sub(
        r"H (\d+\.\d+)m", lambda m: "H 1e38m" if next(count) % 4 == 0 else m.group(0), text
    )
    (d / "clip.srt").write_text(text, encoding="utf-8")


def srt_dated_layout(d: Path, shared: Path) -> None:
    """The Mavic Pro layout with the timing lines replaced by date-time lines (older firmware)."""
    entries = (
        (shared / "real/dji/mavic_pro.SRT").read_text(encoding="utf-8").strip().split("\n\n")[:40]
    )
    out = []
    for k, e in enumerate(entries):
        lines = e.split("\n")
        out.append(
            "\n".join(
                [
                    lines[0],
                    f"2017.07.03 10:{15 + k // 60:02d}:{k % 60:02d}",
                    *[line for line in lines[2:] if "-->" not in line],
                ]
            )
        )
    (d / "clip.srt").write_text("\n\n".join(out) + "\n", encoding="utf-8")


def srt_blank_line_inside(d: Path, shared: Path) -> None:
    """An enterprise layout: a blank line inside every entry (between its two telemetry lines)."""
    entries = (
        (shared / "real/dji/matrice_300.srt").read_text(encoding="utf-8").strip().split("\n\n")[:30]
    )
    out = ["\n".join(e.split("\n")[:3]) + "\n\n" + "\n".join(e.split("\n")[3:]) for e in entries]
    (d / "clip.srt").write_text("\n\n".join(out) + "\n", encoding="utf-8")


def srt_without_gimbal_in_manifest(d: Path, shared: Path) -> None:
    """A manifest naming a DJI subtitle with no gimbal attitude (P4 Pro sample), over a scene."""
    from app.simulate.phone import write_video

    entries = (shared / "real/dji/p4p_sample.SRT").read_text(encoding="utf-8")
    (d / "drone").mkdir()
    (d / "drone/clip.srt").write_text(entries, encoding="utf-8")
    write_video(d / "drone/clip.mp4", np.arange(150) / 30.0, (96, 54), 0)
    (d / "drone/ground.obj").write_text(
        "v -3000 -3000 0\nv 3000 -3000 0\nv 3000 3000 0\nv -3000 3000 0\nf 1 2 3\nf 1 3 4\n"
    )
    lat, lon = _first_srt_position(entries)
    (d / "drone/session.toml").write_text(
        f'[scene]\npath = "ground.obj"\norigin = [{lat}, {lon}, 0.0]\n\n[video]\npath = "clip.mp4"\nstart_time = 0.0\n\n'
        f'[camera]\nhfov_deg = 73.7\n\n[sensors]\nformat = "none"\n\n[gnss]\npath = "clip.srt"\ntakeoff_height_m = 0.0\n'
    )


def _first_srt_position(text: str) -> tuple[float, float]:
    m = re.search(r"GPS\s*\(\s*([-\d.]+)\s*,\s*([-\d.]+)", text)
    return float(m.group(2)), float(m.group(1))  # GPS (lon, lat, ...)


def gpx_bad_numbers(d: Path, shared: Path) -> None:
    text = (shared / "real/gpx/around-visnjan-with-car.gpx").read_text(encoding="utf-8")
    text = text.replace("<ele>", "<ele>x", 3)
    text = re.sub(r"<time>", "<speed>fast</speed><time>", text, count=2)
    (d / "track.gpx").write_text(text, encoding="utf-8")


def gpx_latitude_95(d: Path, shared: Path) -> None:
    text = (shared / "real/gpx/around-visnjan-with-car.gpx").read_text(encoding="utf-8")
    (d / "track.gpx").write_text(re.sub(r'lat="[-\d.]+"', 'lat="95.0"', text), encoding="utf-8")


def gopro_unknown_orin(d: Path, shared: Path) -> None:
    data = bytearray((shared / "real/gopro/max-heromode.mp4").read_bytes())
    for m in re.finditer(b"ORINc\x03\x00\x01", bytes(data)):
        data[m.end() : m.end() + 3] = b"ZQY"
    (d / "gopro.mp4").write_bytes(bytes(data))


def gopro_zero_cori(d: Path, shared: Path) -> None:
    data = bytearray((shared / "real/gopro/max-heromode.mp4").read_bytes())
    assert zero_gpmf_key(data, b"CORI") > 0
    (d / "gopro.mp4").write_bytes(bytes(data))


def gopro_zero_accl(d: Path, shared: Path) -> None:
    data = bytearray((shared / "real/gopro/max-heromode.mp4").read_bytes())
    assert zero_gpmf_key(data, b"ACCL") > 0
    (d / "gopro.mp4").write_bytes(bytes(data))


def gopro_raw_payload(d: Path, shared: Path) -> None:
    shutil.copy(shared / "real/gopro/hero6.raw", d / "hero6.gpmd")


def script_not_utf8(d: Path) -> None:
    (d / "script.txt").write_bytes(b"0.0 play\n1.0 \xff\xfe quit\n")


def photo_copy(d: Path) -> None:
    from app.simulate.sample import SAMPLE_PHOTO

    shutil.copy(SAMPLE_PHOTO, d / "photo.jpg")


def nothing(d: Path) -> None:
    """The clean session, for output-path and option cases."""


# --- 3D Tiles and DEM layers ----------------------------------------------------------------------

PHONE_ORIGIN = (34.80, 113.53, 110.0)


def _ground_tileset(folder: Path, north_m: float = 0.0) -> Path:
    """A tileset of one b3dm: a 400 m square of ground at the phone session's origin height,
    its centre north_m north of the origin (RTC_CENTER, region volume)."""
    from app.geodesy.enu import LocalFrame
    from app.scene import shapes
    from app.scene.tiles import write as tjw
    from app.simulate import tileset as tw

    frame = LocalFrame(*PHONE_ORIGIN)
    quad = shapes.quad([-200, north_m - 200, 0], [400, 0, 0], [0, 400, 0])
    rtc = frame.enu_to_ecef(np.array([0.0, north_m, 0.0]))
    (folder / "ground.b3dm").write_bytes(
        tw.b3dm(tw.glb(frame.enu_to_ecef(quad.vertices) - rtc, quad.faces), rtc)
    )
    region = tw.region_of(frame, [-200, north_m - 200, -1], [200, north_m + 200, 1])
    return tjw.write_json(
        folder / "tileset.json",
        {
            "asset": {"version": "1.0"},
            "geometricError": 10,
            "root": {
                "boundingVolume": {"region": region},
                "geometricError": 0,
                "refine": "REPLACE",
                "content": {"uri": "ground.b3dm"},
            },
        },
    )


def tileset_scene(d: Path) -> None:
    _ground_tileset(d / "session")
    set_manifest(d / "session/session.toml", "scene", "path", '"tileset.json"')


def tileset_far_away(d: Path) -> None:
    _ground_tileset(d / "session", north_m=5000.0)
    set_manifest(d / "session/session.toml", "scene", "path", '"tileset.json"')


def tileset_without_root(d: Path) -> None:
    (d / "session/tileset.json").write_text('{"asset": {"version": "1.0"}, "geometricError": 1}')
    set_manifest(d / "session/session.toml", "scene", "path", '"tileset.json"')


def _dem(d: Path, lat: float, lon: float, holes: bool = False) -> Path:
    from app.simulate.terrain import write_geotiff

    step = 1.0 / 3600
    h = np.full((240, 240), 110.0 - 20.0)
    if holes:
        h[100:140, 100:140] = np.nan
    return write_geotiff(
        d / "session/dem.tif", h, "EPSG:4326", lon - 120 * step, lat + 120 * step, step, step
    )


def _with_dem(d: Path) -> None:
    text = (d / "session/session.toml").read_text()
    (d / "session/session.toml").write_text(text + '\n[dem]\npath = "dem.tif"\n')


def dem_with_holes(d: Path) -> None:
    _dem(d, PHONE_ORIGIN[0], PHONE_ORIGIN[1], holes=True)
    _with_dem(d)


def dem_far_away(d: Path) -> None:
    _dem(d, PHONE_ORIGIN[0] + 0.5, PHONE_ORIGIN[1])
    _with_dem(d)


def dem_not_a_geotiff(d: Path) -> None:
    (d / "session/dem.tif").write_bytes(b"II*\x00" + b"\x00" * 64)
    _with_dem(d)


def tileset_and_photo(d: Path) -> None:
    tileset_scene(d)
    photo_copy(d)


def dem_under_gopro_clip(d: Path, shared: Path) -> None:
    """A DEM (flat, 1 arc-second, 0.04 deg square) around the first GPS fix of a real GoPro clip."""
    from app.attitude.gopro import read_gopro
    from app.core.messages import Messages
    from app.simulate.terrain import write_geotiff

    rec = read_gopro(shared / "real/gopro/max-heromode.mp4", Messages())
    lat, lon = float(rec.gnss.lat[0]), float(rec.gnss.lon[0])
    step = 1.0 / 3600
    write_geotiff(
        d / "dem.tif",
        np.full((144, 144), float(rec.gnss.h[0]) - 60.0),
        "EPSG:4326",
        lon - 72 * step,
        lat + 72 * step,
        step,
        step,
    )


def dem_vertical_unknown(d: Path) -> None:
    _dem(d, PHONE_ORIGIN[0], PHONE_ORIGIN[1])
    text = (d / "session/session.toml").read_text()
    (d / "session/session.toml").write_text(
        text + '\n[dem]\npath = "dem.tif"\nvertical = "navd88"\n'
    )
