"""A video archive on a map (`geofuse index`, `geofuse find`): clips found and indexed on Dask
distributed into GeoParquet footprints (clips.py, index.py, store.py), and queried by place and
time (find.py)."""

from app.archive.clips import ClipResult, find_clips, index_clip
from app.archive.find import Hit, find, place_of
from app.archive.index import IndexReport, index_archive
from app.archive.store import read_clips, read_footprints

__all__ = [
    "ClipResult",
    "Hit",
    "IndexReport",
    "find",
    "find_clips",
    "index_archive",
    "index_clip",
    "place_of",
    "read_clips",
    "read_footprints",
]
