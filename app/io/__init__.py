"""Readers: files -> frozen records of numpy arrays. Each reader names the file, line and field
in its errors and counts what it repaired in `messages`. No reader writes to its input."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
