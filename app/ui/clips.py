"""Further clips in the viewer, played with the open session on one timeline (app.session.timeline):
each with its own session, pose solver, decoder (its own worker thread) and attitude source,
drawn as a further projector (FusionRenderer.set_extra_projectors) on the open session's scene.

Each frame, the timeline time of the frame the first clip shows says which frame every other
clip shows (none outside its span; where more than MAX_EXTRA have one, those nearest in time are
drawn, said once as the clips are added); a clip's player follows the first's clock (seeked when it
strays by more than STRAY_S, paused and sped with it). A hidden clip's decoder and textures are
released; showing it again starts a new one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from app.camera.pinhole import Camera
from app.core.errors import GeofuseError
from app.footage.clips import onto, open_any
from app.playback.library import SolverLibrary
from app.playback.player import Player
from app.render.passes import MAX_EXTRA
from app.render.renderer import beyond_message
from app.render.video_texture import YuvPlanes
from app.session.config import ClipRef
from app.session.model import Session
from app.session.timeline import Timeline

__all__ = [
    "OtherClip",
    "add",
    "close_all",
    "set_alpha",
    "set_offset",
    "set_source",
    "set_visible",
    "update",
]

STRAY_S = 0.25  # a further clip's player is seeked when its clock strays this far
CLIP_COLOURS = (  # frustum colours of the further clips, in turn
    (0.2, 0.8, 1.0, 1.0), (1.0, 0.4, 0.8, 1.0), (0.6, 1.0, 0.3, 1.0), (1.0, 0.55, 0.2, 1.0),
    (0.7, 0.5, 1.0, 1.0), (0.3, 1.0, 0.9, 1.0), (1.0, 1.0, 1.0, 1.0),
)  # fmt: skip


@dataclass
class OtherClip:
    """A further clip: its session, solver library, player (None while hidden), attitude
    source, whether shown, its offset on the timeline (s), priority, and what it shows."""

    session: Session
    library: SolverLibrary
    player: Player | None
    source: str
    visible: bool = True
    offset_s: float = 0.0
    priority: float = 0.0
    alpha: float | None = None  # its opacity over the model (None: the Projection panel's)
    colour: tuple[float, float, float, float] = CLIP_COLOURS[0]
    frame: int | None = None
    move: Callable[[Camera], Camera] | None = None  # its cameras onto the first clip's scene


def retime(v) -> None:
    """The timeline of the open session and its further clips (their offsets applied)."""
    L = v.loaded
    L.timeline = Timeline.of(
        [L.session, *(c.session for c in L.others)], [0.0, *(c.offset_s for c in L.others)]
    )


def add(v, path: Path, ref: ClipRef | None = None) -> None:
    """Open a further clip (a manifest or a camera file) beside the open session; ref: its
    [[clips]] table's settings (offset, priority, opacity, source)."""
    L = v.loaded
    if L is None:
        raise GeofuseError("open a session first; further clips play beside it")
    session = open_any(path, accuracy_m=v.options.gnss_accuracy_m)  # every clip on the timeline
    L.others.append(
        OtherClip(
            session,
            SolverLibrary(session, first=session.sources[0]),
            Player(session.video),
            session.sources[0],
            colour=CLIP_COLOURS[len(L.others) % len(CLIP_COLOURS)],
            move=onto(session, L.session),
        )
    )
    if ref is not None:
        clip = L.others[-1]
        clip.offset_s, clip.priority, clip.alpha = ref.offset_s, ref.priority, ref.alpha
        if ref.source is not None:
            session.check_source(ref.source)
            clip.source = ref.source
    retime(v)
    beyond = len(L.others) - MAX_EXTRA
    if beyond > 0:  # said once, with how many: the warning of one clip fewer gives way
        said = [w for w in v.ui.warnings if w != beyond_message(beyond - 1)]
        v.ui.warnings = [*said, beyond_message(beyond)]


def set_visible(v, index: int, on: bool) -> None:
    """Show or hide further clip `index` (from 1); hiding releases its decoder."""
    clip = _clip(v, index)
    clip.visible = on
    if not on and clip.player is not None:
        clip.player.close()
        clip.player, clip.frame = None, None
    elif on and clip.player is None:
        clip.player = Player(clip.session.video)


def set_offset(v, index: int, offset_s: float) -> None:
    """Move further clip `index` (from 1) on the timeline by offset_s seconds."""
    _clip(v, index).offset_s = float(offset_s)
    retime(v)


def set_source(v, index: int, name: str) -> None:
    """Further clip `index` (from 1) under another pose source."""
    clip = _clip(v, index)
    clip.session.check_source(name)
    clip.source = name


def set_alpha(v, index: int, alpha: float) -> None:
    """Further clip `index`'s opacity over the model, 0..1."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"expected an opacity in [0, 1], got {alpha:g}")
    _clip(v, index).alpha = float(alpha)


def _clip(v, index: int) -> OtherClip:
    others = v.loaded.others
    if not 1 <= index <= len(others):
        raise ValueError(f"there are {len(others)} further clips; got {index}")
    return others[index - 1]


def _planes(clip: OtherClip) -> YuvPlanes:
    """The clip's current frame as stored, turned and converted to RGB by the renderer (GPU)."""
    f = clip.player.current
    return YuvPlanes(f.y, f.u, f.v, clip.session.rotation_cw, f.bt709, f.full_range)


def update(v, now: float, wait_s: float = 0.0) -> None:
    """Every further clip's frame at the first clip's timeline time, drawn as a projector
    (wait_s: how long to wait for a frame to be decoded, as the first clip's player does)."""
    L = v.loaded
    if L is None or not L.others:
        return
    k0 = v.current_index
    t = float(L.timeline.clips[0].times[k0]) if k0 >= 0 else None
    # The moment drawn: the first clip's clock, a little after its frame's time.
    first_age = max(0.0, L.clock.time(now) - float(L.session.video.pts_s[k0])) if k0 >= 0 else 0.0
    views, key, ages = [], [], []
    for clip, span in zip(L.others, L.timeline.clips[1:], strict=True):
        clip.frame = None if t is None or not clip.visible else span.frame_at(t)
        p = clip.player
        if clip.frame is None or p is None:
            continue
        target = float(clip.session.video.pts_s[clip.frame])
        if p.clock.paused != L.clock.paused or abs(p.clock.time(now) - target) > STRAY_S:
            p.clock.set_speed(L.clock.speed, now)
            p.seek(target, now)
            p.clock.set_paused(L.clock.paused, now)
        p.tick(now, wait_s=wait_s)
        track = clip.library.track(clip.source)
        if p.current is None or track is None or p.index < 0:
            continue
        camera = clip.move(track.frame_camera(p.index))
        views.append((camera, clip, clip.priority))
        key.append((id(clip), p.index, camera.position, camera.orientation, clip.alpha))
        ages.append(max(0.0, t + first_age - float(span.times[p.index])))
    if tuple(key) != L.extras_shown:
        L.renderer.set_extra_projectors(
            [(cam, _planes(c), prio) for cam, c, prio in views],
            [v.ui.settings.alpha if c.alpha is None else c.alpha for _, c, _ in views],
            [c.colour for _, c, _ in views],
            ages,
        )
        L.extras_shown = tuple(key)
    L.renderer.set_ages(first_age, ages)


def close_all(loaded) -> None:
    for clip in loaded.others:
        if clip.player is not None:
            clip.player.close()
        clip.library.close()
    loaded.others = []
