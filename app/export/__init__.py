"""Exports for GIS tools: frame records (records.py), footprints and tracks as GeoJSON/KML/KMZ and
an FMV metadata CSV (gis.py), MISB ST 0601 KLV in an MPEG transport stream (klv.py), and the fused
view as a video (video.py)."""

__all__ = ["EXPORT_SUFFIXES"]

EXPORT_SUFFIXES = {
    "footprints": (".geojson", ".json", ".kml", ".kmz"),
    "fmv-csv": (".csv",),
    "klv": (".ts",),
    "video": (".mp4",),
    "ortho": (".tif", ".tiff"),
    "model": (".glb", ".json"),
}
