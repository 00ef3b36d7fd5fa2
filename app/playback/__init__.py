"""Playback: a pure media clock, and a decoder worker thread feeding a bounded frame queue."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
