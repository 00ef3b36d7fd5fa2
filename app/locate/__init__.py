"""Where a video pixel lies on the model (location: the ray through the lens followed by the
position pass, occlusion included, with the pose's error per source), and the marks and measures
made from such picks (marks, pure)."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
