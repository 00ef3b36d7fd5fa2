"""The world around a clip from tile services: imagery (XYZ/TMS, WMTS in any tile matrix set,
MBTiles, PMTiles, GeoPackage, a GeoTIFF/COG over HTTP) and terrain (Terrain-RGB, Terrarium PNG
tiles from any of those, a DEM GeoTIFF/COG, Cesium quantized-mesh by its layer.json) fetched
over the clip's track, cached on disk, and mosaicked into a DEM and an orthophoto that the
scene's DEM path (app.scene.terrain) drapes; pre-fetched for offline use (app.world.prefetch,
`geofuse cache`)."""
