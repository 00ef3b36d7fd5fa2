"""Procedural, reproducible sample data: the sample site (and, later, a ground-truth session)."""
