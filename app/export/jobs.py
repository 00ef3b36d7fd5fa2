"""One export of a solved session to a file, as `geofuse export` runs it: the frames chosen, the
file written atomically (app.core.outputs), and the line that says what was written."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from app.camera.frame_time import frame_span
from app.core.errors import GeofuseError
from app.core.imageio import write_rgb
from app.core.outputs import check_output, write_atomically, write_via_path
from app.export.gis import COMPANIONS, borders_geojson, companion, track_geojson, write_records
from app.export.klv import carried_by_imu, is_registered, write_klv_ts
from app.export.preview import footprint_preview
from app.export.records import FrameRecord, frame_records
from app.export.video import FurtherClip, export_video
from app.footage.clips import onto
from app.render.passes import MAX_EXTRA
from app.render.renderer import beyond_message
from app.scene.layers import scene_credit
from app.session.camera_track import CameraTrack
from app.session.model import Session
from app.session.timeline import Timeline

__all__ = ["ExportOptions", "export_session", "write_footprints"]


@dataclass(frozen=True)
class ExportOptions:
    """every: one record per `every` frames (footprints, fmv-csv, klv); size: (w, h) px of the
    video or the preview; view: the video's window camera; start_s, end_s: the video's span
    (media s, None: the clip's ends); preview: a PNG of the footprints over the scene, or None;
    name: the KML document's name."""

    every: int = 1
    size: tuple[int, int] = (1280, 720)
    view: str = "follow"
    start_s: float | None = None
    end_s: float | None = None
    preview: Path | None = None
    name: str = "geofuse"


def export_session(
    what: str,
    session: Session,
    source: str,
    track: CameraTrack,
    out: Path,
    options: ExportOptions,
    progress: Callable[[float], None] | None = None,
    further: tuple[tuple[Session, CameraTrack, float, float], ...] = (),
) -> str:
    """Write `what` (footprints, fmv-csv, klv or video; app.export.EXPORT_SUFFIXES) of the
    session under attitude `source` (its solved `track`) to `out`; returns what was written, in
    a line. further: (session, solved track, offset s, priority) of clips drawn in the video
    with this one, on one timeline. Raises GeofuseError for a span without frames."""
    out = Path(out)
    if what != "video" and session.utc_of(float(session.frame_times[0])) is None:
        session.messages.add(
            f"{session.path.name}: no UTC clock is known for this clip (no GPS time, dated subtitle or Unix-time log): "
            "the footprints' utc is empty, and the KLV and CSV time stamps count from 1970-01-01 at the session's time 0"
        )
    if what == "video":
        try:
            first, last = frame_span(session.video.pts_s, options.start_s, options.end_s)
        except ValueError as exc:
            raise GeofuseError(f"--from/--to: {exc}") from exc
        n = [0]

        clips = _further_clips(session, further)

        def write_video(tmp: Path) -> None:
            n[0] = export_video(
                session.video,
                session.rotation_cw,
                track,
                session.scene(),
                tmp,
                options.size,
                options.view,
                first,
                last,
                progress,
                clips,
                scene_credit(session.layers),
            )

        write_via_path(out, "--out", write_video)
        w, h = options.size
        more = f", with {len(clips)} further clips" if clips else ""
        if len(clips) > MAX_EXTRA:  # drawn where they have a frame: the nearest in time then
            more += f"; {beyond_message(len(clips) - MAX_EXTRA)}"
        return f"wrote {out}: {n[0]} frames, {w}x{h}, view {options.view}, attitude from {source}{more}"
    records = list(frame_records(session, source, options.every, progress=progress, track=track))
    if what == "klv":
        n, registered, inertial = [0], is_registered(track), carried_by_imu(track)
        write_via_path(
            out,
            "--out",
            lambda tmp: n.__setitem__(
                0,
                write_klv_ts(session.video, records, tmp, registered=registered, inertial=inertial),
            ),
        )
        said = ", each saying so (item 98)" if registered else ""
        if any(r.gnss is not None for r in records):
            said += ", and what positioned it (item 124: GNSS, or the IMU where it was not used)"
        return f"wrote {out}: the video with {n[0]} MISB ST 0601 local sets, attitude from {source}{said}"
    return write_footprints(records, out, options, list(session.inputs), session, source)


def write_footprints(
    records: list[FrameRecord],
    out: Path,
    options: ExportOptions,
    inputs: list[Path],
    preview_session: Session | None = None,
    source: str = "",
) -> str:
    """Footprints (GeoJSON with its borders and tracks beside it, KML, KMZ) or the FMV CSV of
    the records (one clip's, or several clips' with their clip field) to `out`, never over one
    of `inputs`; the preview drawn over `preview_session`'s scene. Returns the line to print."""
    write_atomically(
        out,
        "--out",
        lambda f: write_records(records, f, out.suffix.lower(), options.name),
        binary=out.suffix.lower() == ".kmz",
    )
    beside = []
    if out.suffix.lower() in (".geojson", ".json"):
        for which, layer in zip(COMPANIONS, (borders_geojson, track_geojson), strict=True):
            path = check_output(companion(out, which), "--out", (out.suffix,), inputs)
            write_atomically(path, "--out", lambda f, layer=layer: json.dump(layer(records), f))
            beside.append(path.name)
    if options.preview is not None and preview_session is not None:
        write_rgb(
            options.preview,
            footprint_preview(
                preview_session.scene(), preview_session.frame, records, options.size
            ),
            "--preview",
            scene_credit(preview_session.layers),
        )
    clipped = sum(r.clipped for r in records)
    clips = len({r.clip for r in records})
    return (
        f"wrote {out}: {len(records)} frames"
        + (f" of {clips} clips" if clips > 1 else "")
        + (f", attitude from {source}" if source else "")
        + (f"; {clipped} footprints clipped at the range limit" if clipped else "")
        + (f"; beside it {' and '.join(beside)}" if beside else "")
    )


def _further_clips(
    session: Session, further: tuple[tuple[Session, CameraTrack, float, float], ...]
) -> tuple[FurtherClip, ...]:
    """The further clips as the video export draws them: their frame at each of the session's
    frames on one timeline, their cameras moved onto its scene (app.footage.clips.onto)."""
    if not further:
        return ()
    line = Timeline.of(
        [session, *(s for s, _, _, _ in further)], [0.0, *(o for _, _, o, _ in further)]
    )
    times = line.clips[0].times
    out = []
    for (s, track, _, priority), span in zip(further, line.clips[1:], strict=True):
        frames = [span.frame_at(float(t)) for t in times]
        out.append(
            FurtherClip(
                s.video,
                s.rotation_cw,
                track,
                frames,
                [
                    0.0 if j is None else float(t - span.times[j])
                    for t, j in zip(times, frames, strict=True)
                ],
                onto(s, session),
                priority,
            )
        )
    return tuple(out)
