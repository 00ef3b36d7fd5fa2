"""Procedural, reproducible sample data: the sample site (and, later, a ground-truth session)."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
