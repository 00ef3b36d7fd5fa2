"""What arrives, kept as MPEG-TS before anything else reads it: the stream's packets copied (no
re-encoding), video and KLV, in the order they came. A transport stream has no index or trailer
to write at the end, and every packet is handed to the file system as it is muxed (through a
small buffer), so a recording stays playable when the process is killed mid-flight."""

from __future__ import annotations

from pathlib import Path

import av

WRITE_BUFFER = 188 * 7  # bytes FFmpeg gathers before it hands them to the file: one datagram


class Recorder:
    """Copies packets from an input container's video and KLV streams into `path`."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._out = av.open(self._file, "w", format="mpegts", buffer_size=WRITE_BUFFER)
        self._streams: dict[str, object] = {}
        self.packets = 0
        self.errors = 0

    def add_input(self, video_stream, klv_stream) -> None:
        """The input's streams (again after a reconnect: the output streams are kept)."""
        if "video" not in self._streams and video_stream is not None:
            self._streams["video"] = self._out.add_stream_from_template(video_stream)
        if "klv" not in self._streams and klv_stream is not None:
            self._streams["klv"] = self._out.add_data_stream("klv")

    def write(self, packet, kind: str) -> None:
        """A copy of one demuxed packet of the input's `kind` stream ('video' or 'klv'); the
        packet itself is left as it was for the decoder."""
        out = self._streams.get(kind)
        if out is None or packet.pts is None and packet.dts is None:
            return
        copy = av.Packet(bytes(packet))
        copy.pts, copy.dts, copy.time_base = packet.pts, packet.dts, packet.time_base
        copy.is_keyframe = packet.is_keyframe
        copy.stream = out
        try:
            self._out.mux(copy)
            self.packets += 1
        except (av.FFmpegError, ValueError):
            self.errors += 1  # a packet FFmpeg refuses (times going back after a reconnect)
        self._file.flush()

    def close(self) -> None:
        try:
            self._out.close()
        except (av.FFmpegError, ValueError):
            pass
        self._file.close()
