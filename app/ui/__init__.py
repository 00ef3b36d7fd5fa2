"""The interactive viewer: window, frame loop, panels, navigation. Only this package needs a window."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
