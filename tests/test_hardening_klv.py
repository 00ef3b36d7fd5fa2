"""Damaged MPEG-TS files and KLV (issue 51): bytes flipped, zeroed, cut off; Local Sets cut short
or claiming absurd lengths; positions jumping to the pole; Precision Time Stamps running
backwards or jumping years; KLV with no position. Each is read as far as it decodes, what was
lost is said in a line naming the file, and nothing ends in a traceback: exit status 0 with a
warning where something usable remains, 2 with one line `FILE: what is wrong` where nothing does.
The inputs are never written."""

from __future__ import annotations

import csv
import hashlib
import math
import random
import struct
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.footage.clips import open_any
from app.io.klv_track import KlvTrack, read_klv, read_raw_klv, steady_stamps
from app.io.misb import encode, local_set, parse, read_ber, read_oid, sets_at
from app.io.video import demux, probe
from app.playback.decoder import Decoder
from app.simulate.feed import UTC_START_S, Orbit, orbit_set, write_feed
from app.simulate.phone import write_video

SIZE = (320, 180)
ORBIT = Orbit()
VFOV_DEG = 30.0
YEAR_S = 365.25 * 86400.0


@pytest.fixture(scope="module")
def feed(tmp_path_factory) -> bytes:
    """The bytes of a good 4 s orbit TS, 30 fps, KLV at 7 Hz on its own times."""
    return write_feed(
        tmp_path_factory.mktemp("good") / "flight.ts", 4.0, SIZE, klv_hz=7.0
    ).read_bytes()


def flipped(data: bytes, seed: int, bits: int = 300) -> bytes:
    """`bits` random bits of `data` flipped (a few hundred bytes damaged in transit)."""
    r = random.Random(seed)
    out = bytearray(data)
    for _ in range(bits):
        out[r.randrange(len(out))] ^= 1 << r.randrange(8)
    return bytes(out)


def zeroed(data: bytes, start: int, length: int) -> bytes:
    out = bytearray(data)
    out[start : start + length] = bytes(length)
    return bytes(out)


DAMAGE = {
    **{f"flip{seed}": (lambda d, s=seed: flipped(d, s)) for seed in range(6)},
    "zero-middle": lambda d: zeroed(d, len(d) // 3, 4000),
    "zero-head": lambda d: zeroed(d, 0, 30000),
    "cut": lambda d: d[: int(len(d) * 0.6) + 77],
}


def rebuilt(raw: bytes, changes: dict[int, bytes]) -> bytes:
    """A Local Set with some items' values replaced (tag: new value bytes), checksum new."""
    length, i = read_ber(raw, 16)
    end = i + length
    items = []
    while i < end:
        tag, i = read_oid(raw, i)
        n, i = read_ber(raw, i)
        if tag != 1:
            items.append((tag, changes.get(tag, raw[i : i + n])))
        i += n
    return local_set(items)


def stamp(us: float) -> bytes:
    return struct.pack(">Q", int(round(us)))


def no_traceback(capsys) -> str:
    """Everything the command printed (stdout and stderr), checked for a traceback."""
    got = capsys.readouterr()
    said = got.out + got.err
    assert "Traceback" not in said and "Error:" not in said.replace("geofuse: error:", "")
    return said


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_demux_ends_where_pyav_meets_a_stream_that_appeared_mid_file():
    """PyAV 18's end-of-file flush indexes its stream list with a stream a damaged transport
    stream's tables added mid-file: IndexError after the last packet. The packets stand."""

    class Container:
        def demux(self, *streams):
            yield "a"
            yield "b"
            raise IndexError("list index out of range")

    assert list(demux(Container())) == ["a", "b"]


@pytest.mark.parametrize("kind", sorted(DAMAGE))
def test_a_damaged_transport_stream_opens_what_decodes_and_says_what_was_lost(
    feed, kind, tmp_path, capsys
):
    path = tmp_path / f"{kind}.ts"
    path.write_bytes(DAMAGE[kind](feed))
    before = sha(path)
    assert main(["telemetry", str(path)]) == 0
    said = no_traceback(capsys)
    warnings = [line for line in said.splitlines() if "warning:" in line]
    assert warnings and all(path.name in line for line in warnings), said
    assert "MISB KLV:" in said and "positions:" in said
    # The viewer's way in: the session opens, the damage said in its messages.
    session = open_any(path)
    assert len(session.video.pts_s) > 60
    lost = " ".join(session.messages.items)
    assert any(w in lost for w in ("damaged", "KLV set(s)", "cut short")), lost
    assert sha(path) == before


@pytest.mark.parametrize("kind", ["flip5", "zero-head"])
def test_solve_and_render_take_a_damaged_transport_stream(feed, kind, tmp_path, capsys):
    path = tmp_path / f"{kind}.ts"
    path.write_bytes(DAMAGE[kind](feed))
    out = tmp_path / "poses.csv"
    assert main(["solve", str(path), "--out", str(out)]) == 0
    no_traceback(capsys)
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) > 60 and all(math.isfinite(float(r["U"])) for r in rows)
    png = tmp_path / "frame.png"
    code = main(
        ["render", "--session", str(path), "--time", "2", "--out", str(png), "--size", "160x90"]
    )
    no_traceback(capsys)
    assert code in (0, 1) and png.is_file()


def test_the_viewers_decoder_plays_a_damaged_transport_stream_to_its_end(feed, tmp_path):
    """The viewer's decoder plays the damaged stream through to its last frame without an error.
    How many frames the flipped bits cost depends on where they land in the encoder's bytes (a
    keyframe hit loses its group of pictures, 30 frames here: 88 of 118 with PyAV 18.1's FFmpeg,
    more than 90 with earlier builds), so the count asked is what a stream that lost at most one
    second of its four still has: two thirds of the frames the container holds."""
    path = tmp_path / "flip5.ts"
    path.write_bytes(DAMAGE["flip5"](feed))
    info = probe(path)
    dec = Decoder(path, info.origin_s)
    try:
        frames = []
        # at_end is set once the last frame is queued; up to a queue's worth may still wait in it
        while dec.error is None and not (dec.at_end and dec.frames.empty()):
            try:
                frames.append(dec.frames.get(timeout=30.0))
            except Exception:  # queue.Empty: at the end, nothing more comes
                break
        assert dec.error is None
        assert frames and frames[-1].pts_s >= info.pts_s[-1] - 1.5 / 30.0  # (both from 0)
        assert len(frames) >= 2 * len(info.pts_s) / 3, (len(frames), len(info.pts_s))
    finally:
        dec.close()


@pytest.mark.parametrize(
    ("kind", "make"),
    [
        ("tiny", lambda d: d[:500]),
        ("all-zero", lambda d: zeroed(d, 1000, len(d))),
        ("no-sync", lambda d: bytes(b ^ 0x5A for b in d)),
        ("flip-many", lambda d: flipped(d, 11, 1500)),
    ],
)
def test_a_transport_stream_with_nothing_usable_is_one_line_and_status_2(
    feed, kind, make, tmp_path, capsys
):
    path = tmp_path / f"{kind}.ts"
    path.write_bytes(make(feed))
    for args in (["telemetry", str(path)], ["solve", str(path), "--out", str(tmp_path / "p.csv")]):
        assert main(args) == 2
        said = no_traceback(capsys)
        errors = [line for line in said.splitlines() if "error" in line]
        assert len(errors) == 1 and str(path) in errors[0], said
    with pytest.raises(DataFormatError, match=kind):
        open_any(path)


def _packets(n: int, hz: float = 5.0) -> list[tuple[float, bytes]]:
    return [(k / hz, orbit_set(ORBIT, k / hz, VFOV_DEG)) for k in range(n)]


def test_sets_cut_short_or_claiming_absurd_lengths_are_counted_and_said(tmp_path, capsys):
    packets = _packets(20)
    t4, raw4 = packets[4]
    packets[4] = (t4, raw4[:-9])  # cut short
    t9, raw9 = packets[9]
    _, start = read_ber(raw9, 16)
    absurd = raw9[:16] + b"\x84\x7f\xff\xff\xff" + raw9[start:]  # claims 2 GB
    t10, raw10 = packets[10]
    packets[9] = (t9, absurd + raw10)  # and a good set after it in the same packet
    del packets[10]
    path = write_video(tmp_path / "cut.ts", np.arange(120) / 30.0, SIZE, 0, crf=35, klv=packets)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert track.counts.cut == 2 and len(track.sets) == 18  # the set after the absurd one read
    said = " ".join(messages.items)
    assert "cut.ts: 2 KLV set(s) dropped: cut short or claiming more bytes" in said
    assert "(first at packet 5, byte 0: the set says" in said
    assert main(["telemetry", str(path)]) == 0
    assert "2 KLV set(s) dropped" in no_traceback(capsys)


def test_a_raw_klv_set_cut_short_does_not_take_the_next_set_with_it(tmp_path, capsys):
    sets = [raw for _, raw in _packets(10)]
    data = b"".join(raw[:-12] if k == 3 else raw for k, raw in enumerate(sets))
    dropped: list[tuple[int, str]] = []
    found = [parse(raw) for _, raw in sets_at(data, dropped)]
    assert len(found) == 9 and len(dropped) == 1
    assert dropped[0][0] == sum(len(s) for s in sets[:3]) and "next set begins" in dropped[0][1]
    path = tmp_path / "flight.klv"
    path.write_bytes(data)
    assert main(["telemetry", str(path)]) == 0
    said = no_traceback(capsys)
    assert (
        f"flight.klv: 1 KLV set(s) dropped: cut short or claiming more bytes than their packet holds (first at byte {dropped[0][0]}"
        in said
    )
    assert "9 Local Sets" in said


def test_klv_positions_jumping_to_the_pole_are_dropped_and_said(tmp_path, capsys):
    packets = [
        (t, rebuilt(raw, {13: encode(13, 90.0)}) if k % 4 == 3 else raw)
        for k, (t, raw) in enumerate(_packets(20))
    ]
    path = write_video(tmp_path / "pole.ts", np.arange(120) / 30.0, SIZE, 0, crf=35, klv=packets)
    session = open_any(path)
    said = " ".join(session.messages.items)
    assert "pole.ts: fixes that are not usable positions dropped: 5 jumps" in said
    assert session.gnss is not None and np.all(session.gnss.lat < 35.0)
    out = tmp_path / "poses.csv"
    assert main(["solve", str(path), "--out", str(out)]) == 0
    err = no_traceback(capsys)
    assert "5 jumps" in err
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert max(abs(float(r["N"])) for r in rows) < 500.0  # on the orbit, not 6000 km north
    assert main(["telemetry", str(path)]) == 0
    said = no_traceback(capsys)
    assert "positions: 15 fixes" in said and "5 jumps" in said


def test_precision_time_stamps_running_backwards_or_jumping_years_are_not_used(tmp_path, capsys):
    packets = []
    for k, (t, raw) in enumerate(_packets(20)):
        us = (UTC_START_S + t) * 1e6
        if k % 4 == 1:
            raw = rebuilt(raw, {2: stamp(us + 3 * YEAR_S * 1e6)})  # years ahead
        elif k in (6, 10, 14):
            raw = rebuilt(raw, {2: stamp(us - 3600e6)})  # an hour back
        packets.append((t, raw))
    path = write_video(tmp_path / "stamps.ts", np.arange(120) / 30.0, SIZE, 0, crf=35, klv=packets)
    session = open_any(path)
    said = " ".join(session.messages.items)
    assert "stamps.ts: 8 KLV Precision Time Stamp(s) (tag 2) run backwards or jump" in said
    assert session.utc_at_zero_s == pytest.approx(UTC_START_S, abs=1e-3)
    out = tmp_path / "out.ts"
    assert main(["export", "klv", str(path), "--out", str(out)]) == 0
    no_traceback(capsys)
    exported = read_klv(out, probe(out), Messages())
    us = np.array([s.time_us for s in exported.sets], np.float64) / 1e6 - UTC_START_S
    assert np.all(np.diff(us) > 0) and 0.0 <= us[0] and us[-1] < 5.0


def test_raw_klv_stamps_running_backwards_or_jumping_years_drop_their_sets(tmp_path, capsys):
    sets = [raw for _, raw in _packets(25)]
    sets[10] = rebuilt(sets[10], {2: stamp((UTC_START_S + 2 * YEAR_S) * 1e6)})
    sets[15] = rebuilt(sets[15], {2: stamp((UTC_START_S - 5.0) * 1e6)})
    sets[0] = rebuilt(sets[0], {2: stamp(1e6)})  # 1970
    path = tmp_path / "stamps.klv"
    path.write_bytes(b"".join(sets))
    messages = Messages()
    track = read_raw_klv(path, messages)
    assert len(track.sets) == 22 and track.counts.unplaced == 3
    assert track.t[0] == 0.0 and track.t[-1] == pytest.approx(4.6, abs=1e-6)
    said = " ".join(messages.items)
    assert (
        "stamps.klv: 3 KLV set(s) dropped: their Precision Time Stamps (tag 2) run backwards or jump"
        in said
    )
    out = tmp_path / "track.csv"
    assert main(["telemetry", str(path), "--csv", str(out)]) == 0
    assert "3 KLV set(s) dropped" in no_traceback(capsys)
    with out.open() as f:
        times = [float(r["time_s"]) for r in csv.DictReader(f)]
    assert times == sorted(times) and times[-1] < 5.0


def test_one_presentation_time_for_all_sets_places_them_by_their_steady_stamps():
    track = KlvTrack("x")
    for k in range(10):
        us = (UTC_START_S + k * 0.2) * 1e6 + (50 * YEAR_S * 1e6 if k == 4 else 0.0)
        track.add(rebuilt(orbit_set(ORBIT, k * 0.2, VFOV_DEG), {2: stamp(us)}), 3.0)
    track.finish()
    assert track.counts.unplaced == 1 and len(track.sets) == 9
    assert track.t[0] == 3.0 and track.t[-1] == pytest.approx(4.8, abs=1e-6)


def test_steady_stamps_keep_the_longest_forward_run_without_jumps():
    s = 1_700_000_000_000_000
    y = int(YEAR_S * 1e6)
    assert steady_stamps([s, s + 1, None, s + 2, s + 3]) == [True, True, False, True, True]
    assert steady_stamps([s, s + 1, s + y, s + 2, s + 3]) == [True, True, False, True, True]
    assert steady_stamps([s, s + 1, s - 9, s + 2, s + 3]) == [True, True, False, True, True]
    # A clock set years ahead half way: the longer piece kept.
    assert steady_stamps([s, s + 1, s + y, s + y + 1, s + y + 2]) == [
        False,
        False,
        True,
        True,
        True,
    ]
    assert steady_stamps([]) == []


def test_telemetry_of_klv_with_no_position_says_so(tmp_path, capsys):
    packets = [(t, rebuilt(raw, {13: encode(13, math.nan)})) for t, raw in _packets(10)]
    path = write_video(tmp_path / "blind.ts", np.arange(60) / 30.0, SIZE, 0, crf=35, klv=packets)
    assert main(["telemetry", str(path)]) == 0
    said = no_traceback(capsys)
    assert "blind.ts: no KLV set places the sensor" in said and "no positions" in said
    assert main(["telemetry", str(path), "--csv", str(tmp_path / "t.csv")]) == 2
    assert "holds no positions" in no_traceback(capsys)


@pytest.mark.gl
def test_the_viewer_opens_a_damaged_transport_stream_and_plays_what_decodes(
    feed, display, tmp_path
):
    import json

    from tests.conftest import run_viewer

    path = tmp_path / "flip5.ts"
    path.write_bytes(DAMAGE["flip5"](feed))
    state = tmp_path / "state.json"
    script = tmp_path / "script.txt"
    script.write_text(f"0.0 clock 0.0333333\n0.0 play\n2.0 state {state}\n2.2 quit\n")
    result = run_viewer(display, str(path), "--script", str(script), "--size", "640x360")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Traceback" not in result.stderr
    got = json.loads(state.read_text())
    assert got["errors"] == [] and got["frames_shown"] > 10
    assert any("flip5.ts: the video stream is damaged" in w for w in got["warnings"])
