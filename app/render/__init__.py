"""Everything that touches OpenGL (moderngl). Nothing outside app.render and app.ui imports it.

The renderer is a set of passes over the scene data: the depth pass from the video's camera,
then the scene pass that projects the video (paper 2.2.1-2.2.2), then overlays.
"""

__all__: list[str] = []  # the package exports nothing itself: import its modules
