"""What every room uses and nothing below it: errors that name the file and field, units and
defaults (constants), the message channel (messages), progress bars (progress), safe writes of
outputs (outputs), image files (imageio) and the frozen settings that the renderer, playback and
the viewer share (settings). Imports nothing of the app but itself."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
