"""The world around a clip from tile services: imagery (XYZ/TMS, MBTiles) and terrain
(Terrain-RGB, Terrarium PNG tiles) fetched over the clip's track, cached on disk, and mosaicked
into a DEM and an orthophoto that the scene's DEM path (app.scene.terrain) drapes."""
