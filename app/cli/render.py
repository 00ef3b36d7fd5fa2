"""`geofuse render`: one image projected onto a scene (--image, --pose, --fov/--lens), or a
session's frame at --time with its solved pose (--session), to a PNG."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.camera.frame_time import frame_at
from app.camera.intrinsics import Intrinsics
from app.cli.common import (
    nothing_drawn,
    open_further,
    open_with_source,
    print_messages,
    print_scene_report,
    projection_settings,
    solved,
    still_scene,
)
from app.core.constants import DEFAULT_NEAR_M
from app.core.errors import GeofuseError
from app.core.imageio import write_rgb
from app.core.outputs import IMAGE_SUFFIXES, check_output
from app.core.settings import OverlaySettings
from app.footage.clips import onto
from app.io.video import read_frame
from app.render.still import render_still, window_camera
from app.scene.layers import scene_credit
from app.session.config import ClipRef
from app.session.model import Session
from app.session.timeline import Timeline


def run(args: argparse.Namespace) -> int:
    if args.session is not None:
        return _session(args)
    scene = still_scene(args, "render: give --session MANIFEST --time T, or all of", args.far)
    check_output(args.out, "--out", IMAGE_SUFFIXES, scene.inputs)
    try:
        view_intr = Intrinsics.from_fov(args.size[0], args.size[1], args.view_fov)
    except ValueError as exc:
        raise GeofuseError(f"--view-fov: {exc}") from exc
    projector, image, loaded = scene.camera, scene.image, scene.loaded
    view = window_camera(projector, view_intr, args.view_from, args.look_at, args.far)
    still = render_still(
        loaded.mesh,
        image,
        projector,
        view,
        projection_settings(args),
        OverlaySettings(frustum=not args.no_frustum, trajectory=False),
        extras=[(img, cam, 0.0) for img, cam in scene.extras],
    )
    out = write_rgb(args.out, still.rgb)
    if still.left_out:
        print(f"warning: {still.left_out}", file=sys.stderr)
    shown = f", {1 + len(scene.extras)} images projected" if scene.extras else ""
    print(f"wrote {out} ({still.rgb.shape[1]}x{still.rgb.shape[0]}{shown})")
    print_scene_report(loaded.mesh)
    return 1 if nothing_drawn(still.samples, loaded.mesh) else 0


def _session(args: argparse.Namespace) -> int:
    """The frame shown at --time (app.camera.frame_time.frame_at, as the viewer shows it) with its pose."""
    if args.time is None:
        raise GeofuseError("render --session needs --time T (seconds from the video's first frame)")
    check_output(args.out, "--out", IMAGE_SUFFIXES, [*args.session, *(args.lens or [])])
    session, source = open_with_source(args.session[0], args, IMAGE_SUFFIXES)
    pts = session.video.pts_s
    if not pts[0] - 0.5 <= args.time <= pts[-1] + 0.5:
        raise GeofuseError(
            f"--time {args.time:g}: the video runs from {pts[0]:.3f} to {pts[-1]:.3f} s"
        )
    print_messages(session)
    index = frame_at(pts, args.time)
    try:
        track = solved(session, source).with_clip(DEFAULT_NEAR_M, args.far)
    except ValueError as exc:
        raise GeofuseError(f"--source: {exc}") from exc
    projector = track.frame_camera(index)
    view = window_camera(
        projector,
        Intrinsics.from_fov(args.size[0], args.size[1], args.view_fov),
        args.view_from,
        args.look_at,
        args.far,
    )
    extras, ages, said = _others(args, session, index)
    still = render_still(
        session.scene(),
        read_frame(session.video.path, index, session.video),
        projector,
        view,
        projection_settings(args),
        OverlaySettings(frustum=not args.no_frustum),
        trajectory=track.frame_poses().enu,
        extras=extras,
        ages_s=[0.0, *ages],
    )
    out = write_rgb(args.out, still.rgb, credit=scene_credit(session.layers))
    if still.left_out:
        print(f"warning: {still.left_out}", file=sys.stderr)
    print(f"wrote {out}: frame {index} at {pts[index]:.3f} s, attitude from {source}{said}")
    print_scene_report(session.scene())
    return 1 if nothing_drawn(still.samples, session.scene()) else 0


def _others(args: argparse.Namespace, first: Session, index: int) -> tuple[list, list[float], str]:
    """The further clips' frames (further --session and the first manifest's [[clips]]) at the
    first's frame `index` on one timeline (app.session.timeline), their cameras moved into the first's
    local frame; how long before that moment each frame was taken (s); and what to say of
    them."""
    refs = [ClipRef(path) for path in args.session[1:]]
    refs += [*first.further]
    if not refs:
        return [], [], ""
    sessions = []
    for k, ref in enumerate(refs):
        key = f"clips[{k - len(args.session) + 1}].source"  # the [[clips]] table, from 0
        sessions.append(open_further(ref, args, IMAGE_SUFFIXES, first.path, key))
    line = Timeline.of([first, *(s for s, _ in sessions)], [0.0, *(r.offset_s for r in refs)])
    t = float(line.clips[0].times[index])
    extras, ages, parts = [], [], []
    for (s, source), span, ref in zip(sessions, line.clips[1:], refs, strict=True):
        print_messages(s)
        k = span.frame_at(t)
        name = Path(s.video.path).name
        if k is None:
            parts.append(f"{name} has no frame then")
            continue
        cam = solved(s, source).with_clip(DEFAULT_NEAR_M, args.far).frame_camera(k)
        extras.append((read_frame(s.video.path, k, s.video), onto(s, first)(cam), ref.priority))
        ages.append(t - float(span.times[k]))
        parts.append(f"{name} frame {k}")
    return extras, ages, "; with " + ", ".join(parts)
