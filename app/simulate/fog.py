"""A simulated session whose view is fogged over for a stretch: a copy of it (app.simulate.
session) with its video grey, no texture, between two media times (what a fogged lens, a
featureless wall, water or the sky look like to a matcher), the rest (GNSS, IMU, truth, its
scene) as it was. For the benches and tests of registration where the scene cannot be seen
(bench/bench_registration.py, bench/bench_gnss_lies.py, tests/test_gnss_lies.py).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import av
import numpy as np

from app.io.video import probe, rotate_for_display
from app.simulate.phone import write_video
from app.simulate.session import START_UNIX_S

FOG_GREY = 170  # the fog's level (0-255, each channel)


def fogged_copy(sample: Path, out: Path, fog_s: tuple[float, float]) -> Path:
    """The session in `sample` copied into `out` (an existing folder) with its video fogged
    over fog_s (media seconds from, to: FOG_GREY); returns the copy's manifest. The copy names
    the original's scene."""
    for f in sample.iterdir():
        if f.is_file() and f.name != "clip.mp4":
            shutil.copy(f, out / f.name)
    manifest = out / "session.toml"
    text = manifest.read_text()
    manifest.write_text(
        text.replace('path = "scene.glb"', f'path = "{(sample / "scene.glb").as_posix()}"')
    )
    info = probe(sample / "clip.mp4")
    frames = []
    with av.open(str(sample / "clip.mp4")) as c:
        for fr in c.decode(video=0):
            frames.append(rotate_for_display(fr.to_ndarray(format="rgb24"), info.rotation_cw))
    pts = np.asarray(info.pts_s)

    def frame(k: int) -> np.ndarray:
        if fog_s[0] <= pts[k] < fog_s[1]:
            return np.full_like(frames[k], FOG_GREY)
        return frames[k]

    write_video(
        out / "clip.mp4",
        pts,
        (info.width, info.height),
        info.rotation_cw,
        creation_time=np.datetime_as_string(np.datetime64(int(START_UNIX_S), "s")) + "Z",
        frame=frame,
        crf=30,
    )
    return manifest
