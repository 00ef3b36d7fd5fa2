"""The interactive viewer: window, frame loop, panels, navigation. Only this package needs a window."""
