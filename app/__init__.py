"""geofuse: drape mobile video onto a georeferenced 3D model.

Data flows one way: ``io -> attitude -> trajectory -> playback -> render -> ui``; ``geo`` and
``scene`` serve them. Nothing outside ``app.render`` and ``app.ui`` imports moderngl or glfw.
"""

__all__ = ["__version__"]

__version__ = "0.1.0"
