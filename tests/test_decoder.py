import av
import numpy as np
import pytest

from app.playback.decoder import Decoder
from app.simulate.phone import write_video


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    path = tmp_path_factory.mktemp("clip") / "c.mp4"
    return write_video(path, np.arange(60) / 30.0, (64, 32), 0)


def take(dec, n, timeout=60.0):
    """The next n frames, each waited for on the queue (the timeout only stops a broken decoder
    from hanging the test: queue.Empty then fails it)."""
    return [dec.frames.get(timeout=timeout) for _ in range(n)]


def test_decodes_in_order_into_a_bounded_queue(clip):
    """The queue fills to its bound and the decoder then waits: nothing is dropped, so the frames
    taken after a pause carry on where the first ones stopped."""
    dec = Decoder(clip)
    try:
        frames = take(dec, 20)
        assert [round(f.pts_s * 30) for f in frames] == list(range(20))
        assert frames[0].y.shape == (32, 64) and frames[0].u.shape == (16, 32)
        q = dec.frames
        with q.not_empty:  # every put notifies it: wait for the bound, not for a time
            q.not_empty.wait_for(lambda: q._qsize() >= q.maxsize, timeout=60)
        assert (
            dec.frames.qsize() == dec.frames.maxsize
        )  # the bound is reached (40 frames remain)...
        rest = take(dec, 40)
        assert [round(f.pts_s * 30) for f in rest] == list(
            range(20, 60)
        )  # ...and nothing was lost at it
        assert dec.skipped == 0  # no media time was published: no frame counts as late
    finally:
        dec.close()


def test_seek_delivers_the_exact_frame_with_the_new_serial(clip):
    dec = Decoder(clip)
    try:
        take(dec, 3)
        dec.seek(1.5, serial=7)
        first = None
        for _ in range(100):  # frames of the old serial may still be queued
            f = dec.frames.get(timeout=60)
            if f.serial == 7:
                first = f
                break
        assert first is not None and round(first.pts_s * 30) == 45
    finally:
        dec.close()


def test_corrupt_packets_are_skipped_and_counted(clip, tmp_path):
    """Damage in the middle of a clip is skipped and counted, and decoding goes on to its end:
    every frame whose packet lies before the damage is delivered, in order and once each.
    (How many frames the damage itself costs is FFmpeg's to say: with frame threads an error
    surfaces when a worker reports it, so the count of lost frames beside the counted packets
    varies with the machine's load; it is not asserted.)"""
    data = bytearray(clip.read_bytes())
    rng = np.random.default_rng(3)
    # Scribble over frame data in the middle of the file; MP4 keeps its index (moov) at the end.
    damaged = rng.integers(int(len(data) * 0.3), int(len(data) * 0.6), 40)
    for pos in damaged:
        data[pos : pos + 8] = b"\xff" * 8
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(bytes(data))
    with av.open(str(clip)) as container:
        stream = container.streams.video[0]
        before = {
            round(float(p.pts * stream.time_base) * 30)
            for p in container.demux(stream)
            if p.pts is not None and p.pos + p.size <= damaged.min()
        }
    dec = Decoder(bad)
    try:
        frames = []  # up to the last frame, which the damage (30-60 % into the file) spares
        while not frames or round(frames[-1].pts_s * 30) < 59:
            frames.append(dec.frames.get(timeout=60))
        assert dec.error is None
        assert dec.corrupt_packets > 0  # the damage was met and counted...
        shown = [round(f.pts_s * 30) for f in frames]
        assert len(frames) > 10 and max(shown) >= 55  # ...and decoding went on past it
        assert shown == sorted(set(shown))  # in order, none twice
        assert len(before) >= 10 and before <= set(shown)  # nothing lost before the damage
    finally:
        dec.close()


def test_unreadable_video_reports_an_error(tmp_path):
    bad = tmp_path / "junk.mp4"
    bad.write_bytes(b"not a video")
    dec = Decoder(bad)
    try:
        assert dec.join(timeout=60)  # the thread ends at the error it reports
        assert "junk.mp4" in dec.error
    finally:
        dec.close()


def test_a_transport_stream_with_one_keyframe_seeks_by_decoding_from_its_start(tmp_path):
    """A TS has no index; with a single keyframe FFmpeg's search for the keyframe before a target
    comes back empty. The exact frame is still delivered (the decoder and read_frame decode from
    the start up to it)."""
    import av

    from app.io.video import read_frame

    ts = tmp_path / "long_gop.ts"
    keys = 0
    with av.open(str(ts), "w", format="mpegts") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = 64, 32, "yuv420p"
        s.codec_context.options = {"g": "1000", "sc_threshold": "0", "bf": "0"}
        for k in range(150):
            rgb = np.full((32, 64, 3), k, np.uint8)  # frame k's grey level is k
            for p in s.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                keys += p.is_keyframe
                c.mux(p)
        for p in s.encode():
            keys += p.is_keyframe
            c.mux(p)
    assert keys == 1
    assert abs(float(read_frame(ts, 100).mean()) - 100) < 3
    dec = Decoder(str(ts))
    try:
        dec.seek(3.0, serial=3)
        f = dec.frames.get(timeout=60)
        while f.serial != 3:
            f = dec.frames.get(timeout=60)
        assert round(f.pts_s * 30) == 90
    finally:
        dec.close()
