"""The MISB ST 0601 KLV of a video, as tracks: every Local Set of a file's (or a live stream's) KLV
data stream read on the video's own clock, then the GNSS track, the camera's attitude and the
field of view it describes.

Timing. A KLV packet's presentation time (PTS) is on the transport stream's clock, the video's:
its media time (app.io.video.media_seconds, the video stream's origin) is the set's time, whether
the KLV is synchronous (a set per frame at that frame's PTS) or asynchronous (its own rate and
PTS, interpolated to each frame's time downstream like every other track). A packet without a PTS
takes its set's Precision Time Stamp (tag 2) through the median offset between the two on the
packets that have both; with neither it is dropped and counted.

What is kept. A set failing its checksum is dropped and counted (never half-read); the reserved
error codes are gaps: a set whose position is in error adds no GNSS fix, one whose angles are in
error adds no attitude, and the rest of the set is still used.

EG 0104. Sets of the older Predator UAV Basic Universal Metadata Set (app.io.misb.parse_eg0104)
are read into the same track as ST 0601's, beside them or alone, counted and said; their camera
is their own line of sight (app.io.misb.line_of_sight_orientation).

Report on change. ST 0601 lets a producer leave out of a set the items that have not changed
since an earlier one. The platform's and the sensor's angles and the field of view (CARRIED) are
carried forward from the last set that reported them, at most CARRY_LIMIT_S old (older: left
out, counted and said); an error code reported is carried as the error it is. Positions and the
frame centre are never carried: a set without them is a time without a fix, interpolated between
the fixes around it like any gap. The version (tag 65), sent once, is carried too.

Time stamps that do not move. Where every set has the one presentation time, the sets are placed
by their Precision Time Stamps (tag 2) instead, said; where those do not move either, the KLV
cannot be placed in time and is refused.

Time stamps that run backwards or jump. A set placed by its presentation time keeps its Precision
Time Stamp only within STAMP_LIMIT_S of what the others' say for that time (the median offset
between the two); the others' stamps are not used (for the clip's UTC either), counted and said.
Sets placed by their stamps alone (raw KLV, packets without a PTS, one PTS for all) keep the
longest run of stamps that never goes backwards in the order the sets arrived, cut where
consecutive stamps lie more than STAMP_GAP_S apart (the longest piece kept); the rest cannot be
placed in time and are dropped, counted and said.

Damage. Sets cut short (their packet ends before the length they claim) or whose length cannot be
read are dropped and counted like sets failing their checksum, with where the first was (packet
and byte); positions go through the plausibility gate every GNSS reader uses
(app.io.streams.plausible_fixes: out of range, jumps) when `gnss` is given the messages.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import av
import numpy as np

from app.core.errors import DataFormatError, VideoError
from app.core.messages import INFO, Messages
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.io.misb import (
    EG0104,
    EG0104_ITEMS,
    LOS_NAMES,
    ST0601,
    TAGS,
    KlvError,
    LocalSet,
    camera_orientation,
    find_key,
    is_eg0104,
    parse_any,
    sets_at,
)
from app.io.streams import FloatArray, GnssTrack, OrientationStream, plausible_fixes
from app.io.video import VideoInfo, demux, ffmpeg_reason, media_seconds, open_video

KLV_CODECS = ("klv", "smpte_klv")
CONSISTENCY_LIMIT_DEG = 2.0  # the frame centre further than this from the optical axis: said
PLATFORM_DESIGNATION_TAG = 10
IMAGE_SOURCE_SENSOR_TAG = 11
CARRIED = tuple(TAGS[tag].name for tag in (5, 6, 7, 16, 17, 18, 19, 20, 90, 91)) + LOS_NAMES
# what a set of each standard can hold of CARRIED (a set is filled only with its own kind's items)
CARRIED_BY = {
    ST0601: CARRIED[: -len(LOS_NAMES)],
    EG0104: tuple(n for n in CARRIED if n in {item[0] for item in EG0104_ITEMS.values()}),
}
ANGLE_TAGS = (5, 90, 6, 91, 7, 18, 19, 20)  # what camera_orientation composes
EG0104_ANGLES = (  # what it composes for an EG 0104 set: name, label, whether it must be there
    ("los_azimuth_deg", "Angle to North", True),
    ("los_obliquity_deg", "Obliquity Angle", True),
    ("los_roll_deg", "Sensor Roll Angle", False),
)
CARRY_LIMIT_S = 10.0  # an item left out of a set is taken from a set at most this much older
STAMP_LIMIT_S = 5.0  # a Precision Time Stamp further (s) from what its PTS says is not used
STAMP_GAP_S = 3600.0  # placed by stamps alone: consecutive stamps further apart (s) are a jump


def steady_stamps(stamps_us: list[int | None]) -> list[bool]:
    """Which Precision Time Stamps (microseconds since 1970; None or 0: absent, False) are
    steady, the sets in the order they arrived: the longest run of them that never goes
    backwards, cut where consecutive stamps lie more than STAMP_GAP_S apart, its longest piece
    kept (a stamp running backwards, or jumping years and back, is left out)."""
    idx = [k for k, us in enumerate(stamps_us) if us]
    tails: list[int] = []  # the smallest stamp that ends a run of each length so far
    ends: list[int] = []  # where (in idx) that run ends
    before = [-1] * len(idx)  # the run's previous member (in idx)
    for j, k in enumerate(idx):
        n = bisect.bisect_right(tails, stamps_us[k])
        if n == len(tails):
            tails.append(stamps_us[k])
            ends.append(j)
        else:
            tails[n], ends[n] = stamps_us[k], j
        before[j] = ends[n - 1] if n else -1
    run: list[int] = []
    j = ends[-1] if ends else -1
    while j >= 0:
        run.append(idx[j])
        j = before[j]
    run.reverse()
    pieces: list[list[int]] = [run[:1]]
    for a, b in zip(run, run[1:], strict=False):
        if (stamps_us[b] - stamps_us[a]) / 1e6 > STAMP_GAP_S:
            pieces.append([])
        pieces[-1].append(b)
    keep = [False] * len(stamps_us)
    for k in max(pieces, key=len):
        keep[k] = True
    return keep


@dataclass
class KlvCounts:
    """What reading found: sets read, sets failing their checksum or unreadable, packets with
    no time, sets whose position or angles were in error (gaps)."""

    sets: int = 0
    bad: int = 0
    untimed: int = 0
    first_error: str = ""
    carried: int = 0  # sets that left out items an earlier set reported (report on change)
    stale: int = 0  # sets that left out an item last reported more than CARRY_LIMIT_S before
    stale_names: set[str] = field(default_factory=set)
    frozen: int = 0  # sets placed by their Precision Time Stamps: every PTS was the same
    eg0104: int = 0  # sets read from EG 0104 (the older Predator set)
    packets: int = 0  # KLV packets (payloads) read
    cut: int = 0  # sets cut short or whose length cannot be read (a damaged packet)
    first_cut: str = ""
    stamps_off: int = 0  # Precision Time Stamps not used: too far from what the PTS says
    stamps_off_s: float = 0.0  # the furthest of them (s)
    unplaced: int = 0  # sets placed by their stamps alone, dropped: the stamps ran back or jumped

    def first_fault(self) -> str:
        """'; the first unreadable: WHERE: WHAT' of the first set dropped, or ''."""
        first = self.first_error or self.first_cut
        return f"; the first unreadable: {first}" if first else ""

    def said(self, where: str, messages: Messages) -> None:
        """One warning per kind of fault, with its count; what report on change carried, said
        as information."""
        if self.carried:
            messages.info(
                f"{where}: {self.carried} KLV set(s) leave out items an earlier set reported (ST 0601 report on change): carried forward, at most {CARRY_LIMIT_S:g} s"
            )
        if self.stale:
            messages.add_once(
                "klv-stale",
                f"{where}: {self.stale} KLV set(s) leave out {', '.join(sorted(self.stale_names))} last reported more than {CARRY_LIMIT_S:g} s before: not carried (a gap there)",
            )
        if self.frozen:
            messages.add_once(
                "klv-frozen",
                f"{where}: all {self.frozen} KLV sets have one presentation time: placed by their Precision Time Stamps (tag 2) instead",
            )
        if self.eg0104:
            messages.add_once(
                "klv-eg0104",
                f"{where}: {self.eg0104} KLV set(s) are EG 0104 (the older Predator UAV Basic Universal Metadata Set): read as ST 0601's items, the camera pointed by EG 0104's own angle to north, obliquity and roll",
                INFO,
            )
        if self.bad:
            messages.add_once(
                "klv-bad",
                f"{where}: {self.bad} KLV set(s) failed their checksum or could not be read and were dropped (first: {self.first_error})",
            )
        if self.cut:
            messages.add_once(
                "klv-cut",
                f"{where}: {self.cut} KLV set(s) dropped: cut short or claiming more bytes than their packet holds (first at {self.first_cut})",
            )
        if self.stamps_off:
            messages.add_once(
                "klv-stamps-off",
                f"{where}: {self.stamps_off} KLV Precision Time Stamp(s) (tag 2) run backwards or jump (up to {self.stamps_off_s:.3g} s from what the presentation times say, expected within {STAMP_LIMIT_S:g} s): not used, those sets placed by their presentation times",
            )
        if self.unplaced:
            messages.add_once(
                "klv-unplaced",
                f"{where}: {self.unplaced} KLV set(s) dropped: their Precision Time Stamps (tag 2) run backwards or jump more than {STAMP_GAP_S:g} s from the others, and nothing else places them in time",
            )
        if self.untimed:
            messages.add_once(
                "klv-untimed",
                f"{where}: {self.untimed} KLV packet(s) had neither a presentation time nor a Precision Time Stamp and were dropped",
            )


@dataclass
class KlvTrack:
    """Local Sets in time order: t (N,) media seconds on the video's clock, the sets, and the
    counts of what was dropped. Grows as packets arrive (`add`), so a live stream and a file
    share it."""

    path: str
    t: list[float] = field(default_factory=list)
    sets: list[LocalSet] = field(default_factory=list)
    counts: KlvCounts = field(default_factory=KlvCounts)
    raw: bool = False  # Local Sets with no container (one payload): faults placed by byte only
    _untimed: list[LocalSet] = field(default_factory=list)
    _reported: dict[str, tuple[float, float]] = field(default_factory=dict)  # name: (t, value)
    _version: int | None = None

    def add(self, payload: bytes, t: float | None) -> list[LocalSet]:
        """The sets in one KLV packet's payload, at media time t (None: the packet had no PTS,
        kept aside for `finish`), the items they leave out carried forward; returns the sets
        placed at t."""
        kept: list[LocalSet] = []
        self.counts.packets += 1
        dropped: list[tuple[int, str]] = []
        for offset, raw in sets_at(payload, dropped):
            try:
                s = parse_any(raw)
            except KlvError as exc:
                self.counts.bad += 1
                self.counts.first_error = self.counts.first_error or f"{self._where(offset)}: {exc}"
                continue
            self.counts.sets += 1
            self.counts.eg0104 += s.standard == EG0104
            if t is None or not math.isfinite(t):
                self._untimed.append(s)
                continue
            s = self._carry(s, float(t))
            self.t.append(float(t))
            self.sets.append(s)
            kept.append(s)
        if dropped:
            self.counts.cut += len(dropped)
            offset, reason = dropped[0]
            self.counts.first_cut = self.counts.first_cut or f"{self._where(offset)}: {reason}"
        return kept

    def _where(self, offset: int) -> str:
        """Where a fault lies, for people: the byte (raw KLV) or the packet and its byte."""
        return f"byte {offset}" if self.raw else f"packet {self.counts.packets}, byte {offset}"

    def _carry(self, s: LocalSet, t: float) -> LocalSet:
        """The set with the CARRIED items it leaves out taken from the last set that reported
        them (at most CARRY_LIMIT_S before t), and the version it leaves out (see the module's
        docstring); what it reports is remembered."""
        filled: dict[str, float] = {}
        stale = False
        for name in CARRIED_BY[s.standard]:
            if name in s.values or name not in self._reported:
                continue
            t0, value = self._reported[name]
            if 0.0 <= t - t0 <= CARRY_LIMIT_S:
                filled[name] = value
            elif t > t0:
                self.counts.stale_names.add(name)
                stale = True
        self.counts.stale += stale
        for name, value in s.values.items():
            if name in CARRIED:
                self._reported[name] = (t, value)
        if s.version is not None:
            self._version = s.version
        version = s.version if s.version is not None else self._version
        if not filled and version == s.version:
            return s
        if filled:
            self.counts.carried += 1
        return replace(s, version=version, values={**s.values, **filled})

    def finish(self) -> KlvTrack:
        """Untimed sets placed by their Precision Time Stamps, everything sorted by time; sets
        that all share one presentation time placed by their stamps (see the module's
        docstring). Stamps that run backwards or jump are not used (see the module's
        docstring)."""
        self._unfreeze()
        self._drop_stray_stamps()
        self._untimed = self._steady(self._untimed)
        stamped = [(t, s.time_us) for t, s in zip(self.t, self.sets, strict=True) if s.time_us]
        offset = (
            float(np.median([us / 1e6 - t for t, us in stamped])) if stamped else None
        )  # UTC s - media s
        if offset is None and self.sets == [] and self._untimed:
            stamps = [s.time_us for s in self._untimed if s.time_us]
            offset = min(stamps) / 1e6 if stamps else None  # none timed: the first stamp is 0
        for s in self._untimed:
            if s.time_us and offset is not None:
                self.t.append(s.time_us / 1e6 - offset)
                self.sets.append(s)
            else:
                self.counts.untimed += 1
        self._untimed = []
        order = sorted(range(len(self.t)), key=self.t.__getitem__)
        self.t = [self.t[i] for i in order]
        self.sets = [self.sets[i] for i in order]
        return self

    def _steady(self, sets: list[LocalSet]) -> list[LocalSet]:
        """The sets (in the order they arrived) whose Precision Time Stamps are steady
        (steady_stamps): the others dropped and counted (unplaced); unstamped ones kept."""
        keep = steady_stamps([s.time_us for s in sets])
        self.counts.unplaced += sum(
            1 for s, k in zip(sets, keep, strict=True) if s.time_us and not k
        )
        return [s for s, k in zip(sets, keep, strict=True) if k or not s.time_us]

    def _drop_stray_stamps(self) -> None:
        """Stamps of timed sets further than STAMP_LIMIT_S from the median offset between the
        stamps and the presentation times: not used (the set kept, placed by its PTS)."""
        stamped = [k for k, s in enumerate(self.sets) if s.time_us]
        if not stamped:
            return
        off = np.array([self.sets[k].time_us / 1e6 - self.t[k] for k in stamped])
        far = np.abs(off - np.median(off))
        for k, d in zip(stamped, far, strict=True):
            if d > STAMP_LIMIT_S:
                self.sets[k] = replace(self.sets[k], time_us=None)
                self.counts.stamps_off += 1
                self.counts.stamps_off_s = max(self.counts.stamps_off_s, float(d))

    def _unfreeze(self) -> None:
        """Every set at one presentation time: their times from their Precision Time Stamps,
        the first set's kept; sets without a stamp, or whose stamps run backwards or jump
        (_steady), dropped and counted. KlvError when the stamps do not move either."""
        if len(self.t) < 2 or max(self.t) > min(self.t):
            return
        t0, n = self.t[0], len(self.t)
        steady = self._steady(self.sets)
        placed = [s for s in steady if s.time_us]
        stamps = [s.time_us for s in placed]
        if len(stamps) < 2 or max(stamps) == min(stamps):
            raise KlvError(
                f"all {n} KLV sets have one presentation time ({t0:.3f} s) and no moving Precision Time Stamp (tag 2): the metadata cannot be placed in time"
            )
        self.counts.untimed += len(steady) - len(placed)
        self.sets = placed
        self.t = [t0 + (us - stamps[0]) / 1e6 for us in stamps]
        self.counts.frozen = len(self.t)

    def times(self) -> FloatArray:
        return np.asarray(self.t, np.float64)

    @property
    def readable(self) -> int:
        """Sets read so far, timed or waiting for `finish` to place them."""
        return len(self.sets) + len(self._untimed)

    def values(self, name: str) -> FloatArray:
        """One mapped value (app.io.misb.TAGS name) of every set, NaN where absent or in error."""
        return np.array([s.get(name) for s in self.sets], np.float64)

    def text(self, tag: int) -> str:
        """The most common text a string tag carries (10: platform, 11: sensor), or ''."""
        found = [
            s.other[tag].decode("utf-8", "replace").strip() for s in self.sets if tag in s.other
        ]
        return max(set(found), key=found.count) if found else ""

    def utc_at_zero(self) -> float | None:
        """Unix time (UTC) of media time 0: the median of Precision Time Stamp minus set time."""
        d = [s.time_us / 1e6 - t for t, s in zip(self.t, self.sets, strict=True) if s.time_us]
        return float(np.median(d)) if d else None

    def synchronous(self, frame_pts_s: FloatArray) -> bool:
        """Whether the KLV is a set per frame: as many sets as frames (9 in 10 at least), every
        one on a frame's presentation time (within 1 ms)."""
        if not self.t or len(self.t) < 0.9 * len(frame_pts_s) or len(frame_pts_s) < 2:
            return False
        t = self.times()
        i = np.clip(np.searchsorted(frame_pts_s, t), 1, len(frame_pts_s) - 1)
        near = np.minimum(np.abs(frame_pts_s[i] - t), np.abs(frame_pts_s[i - 1] - t))
        return bool(np.all(near < 1e-3))

    def heights(self, ellipsoid: str, msl: str, lat: FloatArray, lon: FloatArray) -> FloatArray:
        """Ellipsoidal heights (m): the ellipsoid tag where it is given, else the height above
        sea level through EGM2008; NaN where neither."""
        h = self.values(ellipsoid)
        above_sea = self.values(msl) + undulation(np.nan_to_num(lat), np.nan_to_num(lon))
        return np.where(np.isfinite(h), h, above_sea)

    def gnss(self, messages: Messages | None = None) -> GnssTrack | None:
        """The sensor's positions (tags 13, 14, and 75 or 15): sets with any of them in error are
        gaps. None when no set places the sensor. Given `messages`, the positions go through the
        plausibility gate of every GNSS reader (app.io.streams.plausible_fixes: a latitude
        jumping to the pole and back is dropped, said; DataFormatError when none is left)."""
        t = self.times()
        lat, lon = self.values("sensor_latitude_deg"), self.values("sensor_longitude_deg")
        h = self.heights("sensor_ellipsoid_m", "sensor_msl_m", lat, lon)
        ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
        ok &= np.concatenate([[True], np.diff(t) > 0])  # one fix per time
        if ok.sum() == 0:
            return None
        track = GnssTrack(t[ok], lat[ok], lon[ok], h[ok], path=self.path)
        return track if messages is None else plausible_fixes(track, messages)

    def attitude(
        self, note: str = "MISB ST 0601 platform and sensor angles"
    ) -> OrientationStream | None:
        """Camera -> ENU quaternions of the sets whose angles are all valid (app.io.misb.
        camera_orientation); None when none is."""
        t, q = [], []
        for ti, s in zip(self.t, self.sets, strict=True):
            r = camera_orientation(s)
            if r is not None and (not t or ti > t[-1]):
                t.append(ti)
                q.append(r)
        if not t:
            return None
        return OrientationStream(np.asarray(t), np.asarray(q), self.path, note)

    def angle_faults(self) -> str:
        """Which angle items keep sets from an attitude: each tag missing (the heading: no
        default) or the error code, with the number of sets (EG 0104 sets: their angle to north
        or obliquity missing or not a number); '' where none is."""
        n, parts = len(self.sets), []
        eg0104 = [s for s in self.sets if s.standard == EG0104]
        st0601 = [s for s in self.sets if s.standard != EG0104]
        for name, label, needed in EG0104_ANGLES:
            error = sum(1 for s in eg0104 if not math.isfinite(s.values.get(name, 0.0)))
            if error:
                parts.append(f"EG 0104 {label} is not a number in {error} of {n} sets")
            missing = sum(1 for s in eg0104 if name not in s.values)
            if needed and missing:
                parts.append(f"EG 0104 {label} is missing from {missing} of {n} sets")
        for tag in ANGLE_TAGS:
            name = TAGS[tag].name
            label = f"tag {tag} ({name.removesuffix('_deg').replace('_', ' ')})"
            error = sum(1 for s in st0601 if not math.isfinite(s.values.get(name, 0.0)))
            if error:
                parts.append(f"{label} is the error code in {error} of {n} sets")
            missing = sum(1 for s in st0601 if name not in s.values)
            if tag == 5 and missing:
                parts.append(f"{label} is missing from {missing} of {n} sets")
        return "; ".join(parts)

    def centre_heights(self) -> FloatArray:
        """Ellipsoidal heights (m) of the frame centres (78, else 25 through the geoid)."""
        lat, lon = self.values("centre_latitude_deg"), self.values("centre_longitude_deg")
        return self.heights("centre_ellipsoid_m", "centre_msl_m", lat, lon)

    def centre_offsets_deg(self) -> FloatArray:
        """(N,) for every set: the angle (deg) between the optical axis its angles give and the
        direction from the sensor to the frame centre it gives (tags 23-25/78); NaN where the
        set lacks a pose or a centre, or the centre is within 1 m of the sensor."""
        out = np.full(len(self.sets), np.nan)
        lat, lon = self.values("sensor_latitude_deg"), self.values("sensor_longitude_deg")
        h = self.heights("sensor_ellipsoid_m", "sensor_msl_m", lat, lon)
        clat, clon = self.values("centre_latitude_deg"), self.values("centre_longitude_deg")
        ch = self.centre_heights()
        for k, s in enumerate(self.sets):
            q = camera_orientation(s)
            row = (lat[k], lon[k], h[k], clat[k], clon[k], ch[k])
            if q is None or not all(math.isfinite(v) for v in row):
                continue
            frame = LocalFrame(lat[k], lon[k], h[k])
            d = frame.geodetic_to_enu([clat[k]], [clon[k]], [ch[k]])[0]
            n = np.linalg.norm(d)
            if n < 1.0:
                continue
            axis = -rotations.to_matrix(q)[:, 2]
            out[k] = math.degrees(math.acos(float(np.clip(axis @ d / n, -1.0, 1.0))))
        return out


def klv_streams(container) -> list:
    """The container's KLV data streams (SMPTE 336M KLV, as FFmpeg names it)."""
    return [s for s in container.streams.data if (s.name or "") in KLV_CODECS]


def has_klv(path: str | Path) -> bool:
    """Whether a video file carries a KLV data stream (False where it cannot be opened)."""
    try:
        with open_video(path) as c:
            return bool(klv_streams(c))
    except (av.FFmpegError, OSError):
        return False


def read_klv(path: str | Path, video: VideoInfo, messages: Messages) -> KlvTrack:
    """Every Local Set of the file's KLV data stream on the video's media clock; faults counted
    and said. A file with several KLV streams (a sensor's and a platform's, or two encoders'):
    each is read, the one with the most readable sets is used and the others are said.
    VideoError when the file has no KLV stream or no set can be read."""
    path = Path(path)
    try:
        with open_video(path) as c:
            streams = klv_streams(c)
            if not streams:
                raise VideoError(path, "no KLV data stream (MISB ST 0601 metadata)")
            tracks = {s.index: KlvTrack(str(path)) for s in streams}
            try:
                for packet in demux(c, *streams):
                    if not packet.size:
                        continue
                    tb = packet.stream.time_base
                    t = (
                        media_seconds(packet.pts, tb, video.origin_s)
                        if packet.pts is not None
                        else None
                    )
                    tracks[packet.stream.index].add(bytes(packet), t)
            except av.FFmpegError:
                messages.add(f"{path.name}: the file is cut short: the KLV read so far is used")
    except (av.FFmpegError, OSError) as exc:
        raise VideoError(path, f"cannot read the KLV stream ({ffmpeg_reason(exc)})") from exc
    index, track = max(tracks.items(), key=lambda kv: (kv[1].readable, -kv[0]))
    if len(tracks) > 1:
        others = ", ".join(f"#{i} ({t.readable} sets)" for i, t in tracks.items() if i != index)
        messages.add(
            f"{path.name}: {len(tracks)} KLV data streams: stream #{index} ({track.readable} Local Sets) is used, not {others}"
        )
    return _finished(track, path, messages, VideoError, "the KLV data stream")


def _finished(track: KlvTrack, path: Path, messages: Messages, error, what: str) -> KlvTrack:
    """The track finished (KlvTrack.finish) and its faults said; `error` (VideoError or
    DataFormatError) naming the file where no set can be placed, or none can be read."""
    try:
        track.finish()
    except KlvError as exc:
        raise error(path, str(exc)) from exc
    track.counts.said(path.name, messages)
    if not track.sets:
        found = track.counts.sets + track.counts.bad
        raise error(
            path,
            f"{what} holds no readable MISB ST 0601 Local Set or EG 0104 set ({found} found{track.counts.first_fault()})",
        )
    return track


RAW_KLV_SUFFIXES = (".klv",)  # Local Sets back to back: what `ffmpeg -map 0:d -f data` writes


def starts_as_klv(path: str | Path) -> bool:
    """Whether a file begins (within its first 64 KiB) with a UAS Datalink Local Set or an EG
    0104 set: raw KLV, whatever its suffix (.bin also holds GoPro GPMF)."""
    with Path(path).open("rb") as f:
        head = f.read(1 << 16)
    return find_key(head) >= 0 or is_eg0104(head)


def read_raw_klv(path: str | Path, messages: Messages, video: VideoInfo | None = None) -> KlvTrack:
    """A file of Local Sets with no container around them, timed by their Precision Time
    Stamps, the first set at 0 s; beside a video, on its clock through its creation time (UTC,
    to the second as containers store it) where it has one, said either way. DataFormatError
    naming the file when no set can be read or placed."""
    path = Path(path)
    track = KlvTrack(str(path), raw=True)
    track.add(path.read_bytes(), None)
    _finished(track, path, messages, DataFormatError, "the raw KLV")
    if video is None:
        return track
    if video.creation_time is not None:
        shift = track.sets[0].time_us / 1e6 - track.t[0] - video.creation_time
        track.t = [t + shift for t in track.t]
        messages.info(
            f"{path.name}: raw KLV placed on the video by its creation time (UTC, to the second): the first set at {track.t[0]:.1f} s"
        )
    else:
        messages.add(
            f"{path.name}: raw KLV beside a video with no creation time: its first set is placed at the first frame (give a time offset if they did not start together)"
        )
    return track


def describe(track: KlvTrack, frame_pts_s: FloatArray) -> str:
    """One line: how many sets, at what rate, synchronous or not, and the ST 0601 versions."""
    t = track.times()
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 0.0
    versions = sorted({s.version for s in track.sets if s.version is not None})
    kind = "synchronous (a set per frame)" if track.synchronous(frame_pts_s) else "asynchronous"
    said = f"ST 0601.{'/'.join(map(str, versions))}" if versions else "ST 0601 (no version tag)"
    eg0104 = sum(1 for s in track.sets if s.standard == EG0104)
    if eg0104 == len(track.sets):
        said = "EG 0104 (UAV Basic Universal Metadata Set)"
    elif eg0104:
        said += f" and {eg0104} EG 0104 sets"
    return f"MISB KLV: {len(t)} Local Sets at {rate:.1f} Hz, {kind}, {said}"
