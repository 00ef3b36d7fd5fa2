"""Sharing what geofuse knows beyond its own screen (issue 53): each drawn frame's pose,
footprint and point of interest, and the marks, handed to sinks (Cursor on Target to TAK, a
browser map) without ever holding up the drawing loop."""
