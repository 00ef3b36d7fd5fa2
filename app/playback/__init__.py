"""Playback: a pure media clock, and a decoder worker thread feeding a bounded frame queue."""
