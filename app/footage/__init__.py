"""Camera files opened as they come, without a manifest: a GoPro, DJI or phone clip with what
its camera wrote becomes a Session (clips); a file's telemetry is listed or written as CSV
(telemetry)."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
