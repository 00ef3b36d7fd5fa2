"""From a session and a source's name to poses: the one entry point every command, the
accuracy report and the viewer's library use (track: solve_track, the frame poses CSV), and the
accuracy report against ground truth (accuracy)."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
