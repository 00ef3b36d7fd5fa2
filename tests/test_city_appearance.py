"""City models' appearance themes and georeferenced textures, written here: the theme asked for
is drawn (CityJSON and CityGML), one the file lacks is refused naming the themes it has, and a
CityGML GeoreferencedTexture (an orthophoto of a roof) lands on the roof where its georeference
(inline or a world file) puts each pixel, checked by rendering the roof from above."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from PIL import Image
from rasterio.transform import from_origin

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.errors import ManifestError, SceneError
from app.scene.city.read import read_city
from app.scene.layers import load_layers
from app.session.config import read_config
from app.simulate.city import cityjson, write_citygml
from tests.test_city import (
    BUILDINGS,
    COMPOUND,
    SITE,
    _check_red_wall,
    _check_wall_quadrants,
    _expected_enu,
    _frame,
    _quadrant_image,
    _render,
    sample_manifest_text,
)

APP = 'xmlns:app="http://www.opengis.net/citygml/appearance/2.0"'


def _plain_image(folder, name: str, rgb: tuple[int, int, int]) -> None:
    (folder / "appearances").mkdir(exist_ok=True)
    Image.fromarray(np.full((16, 16, 3), rgb, np.uint8)).save(folder / "appearances" / name)


def _south_wall_colour(city, frame, gl_ctx) -> np.ndarray:
    """The colour (RGB int) at the middle of A's south wall seen from the south."""
    (x0, y0), _, (x1, _), _ = BUILDINGS[0].footprint
    wall = _expected_enu(frame, (x0 + x1) / 2, y0, 106.0)
    eye = wall + [0.0, -30.0, 0.0]
    camera = Camera.create(
        Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0), eye, look_at_quat(eye, wall), far=2000.0
    )
    return _render(gl_ctx, city.mesh, camera).astype(int)[120, 160]


def test_the_cityjson_theme_asked_for_is_drawn(tmp_path, gl_ctx):
    """A's south wall in two texture themes: "summer" (the four-colour image) and "winter"
    (plain blue). By default the first by name is drawn (summer, the right way up); asked for
    (a session's `theme`), winter; a theme no object names is refused, naming those they do.
    The layer's note names the themes and the one drawn."""
    _quadrant_image(tmp_path)
    _plain_image(tmp_path, "snow.png", (40, 60, 230))
    doc = cityjson(BUILDINGS, COMPOUND, translate=(*SITE, 0.0))
    doc["appearance"] = {
        "textures": [
            {"type": "PNG", "image": "appearances/wall.png"},
            {"type": "PNG", "image": "appearances/snow.png"},
        ],
        "vertices-texture": [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
    }
    solid = doc["CityObjects"]["A"]["geometry"][0]
    summer = [[None] for _ in solid["boundaries"][0]]
    winter = [[None] for _ in solid["boundaries"][0]]
    summer[2] = [[0, 0, 1, 2, 3]]  # the south wall (app.simulate.city.FACES)
    winter[2] = [[1, 0, 1, 2, 3]]
    solid["texture"] = {"winter": {"values": [winter]}, "summer": {"values": [summer]}}
    path = tmp_path / "seasons.city.json"
    path.write_text(json.dumps(doc))
    frame = _frame()

    city = read_city(path, frame)
    _check_wall_quadrants(city, frame, gl_ctx)
    assert any("appearance themes 'summer', 'winter'" in m for m in city.notes.items)

    blue = _south_wall_colour(read_city(path, frame, theme="winter"), frame, gl_ctx)
    assert blue[2] > 2 * max(blue[0], blue[1]), blue

    with pytest.raises(SceneError, match=r"no appearance theme 'autumn'.*'summer', 'winter'"):
        read_city(path, frame, theme="autumn")

    # the file names its default theme: drawn unless another is asked for
    doc["appearance"]["default-theme-texture"] = "winter"
    path.write_text(json.dumps(doc))
    by_default = read_city(path, frame)
    blue = _south_wall_colour(by_default, frame, gl_ctx)
    assert blue[2] > 2 * max(blue[0], blue[1]), blue
    assert any("drawn: 'winter', the file's default" in m for m in by_default.notes.items)
    _check_wall_quadrants(read_city(path, frame, theme="summer"), frame, gl_ctx)

    # the same through a session's layer table
    manifest = tmp_path / "session.toml"
    manifest.write_text(
        sample_manifest_text() + f'\n[[layers]]\npath = "{path}"\ntheme = "winter"\n'
    )
    (layer,) = [x for x in read_config(manifest).layers if x.kind == "city"]
    assert layer.theme == "winter"
    loaded = load_layers((layer,), frame)
    assert sum(p.textured for p in loaded.mesh.primitives) == 1


def _appearance(theme: str, body: str) -> str:
    return (
        f"<app:appearanceMember {APP}><app:Appearance><app:theme>{theme}</app:theme>"
        f"<app:surfaceDataMember>{body}</app:surfaceDataMember></app:Appearance></app:appearanceMember>"
    )


def test_the_citygml_theme_asked_for_is_drawn(tmp_path, gl_ctx):
    """CityGML: an Appearance of theme "rgbTexture" (the four-colour image on A's south wall)
    and one of theme "plain" (an X3DMaterial, red, on the same wall): the first the file names
    is drawn by default, the other when asked for; each alone, not mixed."""
    _quadrant_image(tmp_path)
    path = write_citygml(tmp_path / "themes.gml", BUILDINGS, "EPSG:32632+3855")
    texture = (
        "<app:ParameterizedTexture><app:imageURI>appearances/wall.png</app:imageURI>"
        '<app:target uri="#A_p2"><app:TexCoordList>'
        '<app:textureCoordinates ring="#A_p2_r0">0 0 1 0 1 1 0 1 0 0</app:textureCoordinates>'
        "</app:TexCoordList></app:target></app:ParameterizedTexture>"
    )
    material = (
        "<app:X3DMaterial><app:diffuseColor>0.9 0.1 0.1</app:diffuseColor>"
        "<app:target>#A_p2</app:target></app:X3DMaterial>"
    )
    members = _appearance("rgbTexture", texture) + _appearance("plain", material)
    path.write_text(path.read_text().replace("</core:CityModel>", members + "</core:CityModel>"))
    frame = _frame()
    _check_wall_quadrants(read_city(path, frame), frame, gl_ctx)
    plain = read_city(path, frame, theme="plain")
    assert not any(p.textured for p in plain.mesh.primitives)
    _check_red_wall(plain, frame, gl_ctx)
    with pytest.raises(SceneError, match=r"no appearance theme 'ir'.*'plain', 'rgbTexture'"):
        read_city(path, frame, theme="ir")


ROOF = BUILDINGS[0].footprint  # A's roof: x 480010-480030, y 5550020-5550035, at 112 m


def _georeferenced(uri: str, georef: str, prefer: str = "") -> str:
    return _appearance(
        "rgbTexture",
        f"<app:GeoreferencedTexture><app:imageURI>{uri}</app:imageURI>{prefer}{georef}"
        "<app:target>#A_p1</app:target></app:GeoreferencedTexture>",
    )


def _inline(x0: float, y0: float, a: float, e: float) -> str:
    """A referencePoint (the centre of the image's upper-left pixel) and a north-up
    orientation of a m by e m pixels (e negative: rows go south)."""
    return (
        f"<app:referencePoint><gml:Point><gml:pos>{x0} {y0}</gml:pos></gml:Point></app:referencePoint>"
        f"<app:orientation>{a} 0 0 {e}</app:orientation>"
    )


def _check_roof_quadrants(city, frame, gl_ctx) -> None:
    """Seen from 60 m straight above (north up in the image), A's roof shows the four-colour
    image as the georeference lays it: red north-west, green north-east, blue south-west,
    yellow south-east; each checked at the middle of its quarter of the roof."""
    (x0, y0), _, (x1, y1), _ = ROOF
    centre = _expected_enu(frame, (x0 + x1) / 2, (y0 + y1) / 2, 112.0)
    eye = centre + [0.0, -0.01, 60.0]
    camera = Camera.create(
        Intrinsics(320, 240, 400.0, 400.0, 160.0, 120.0), eye, look_at_quat(eye, centre), far=500
    )
    image = _render(gl_ctx, city.mesh, camera).astype(int)

    def at(x, y):
        uv, _ = camera.project(_expected_enu(frame, x, y, 112.0)[None])
        return image[int(uv[0, 1]), int(uv[0, 0])]

    west, east = x0 + 0.25 * (x1 - x0), x0 + 0.75 * (x1 - x0)
    north, south = y0 + 0.75 * (y1 - y0), y0 + 0.25 * (y1 - y0)
    for (x, y), channel in (((west, north), 0), ((east, north), 1), ((west, south), 2)):
        px = at(x, y)
        assert px[channel] > 1.5 * max(np.delete(px, channel)), (x, y, px)
    yellow = at(east, south)
    assert yellow[0] > 2 * yellow[2] and yellow[1] > 2 * yellow[2], yellow


def test_a_georeferenced_texture_lands_on_the_roof_where_its_georeference_says(tmp_path, gl_ctx):
    """A GeoreferencedTexture (CityGML 2.0) on A's roof: a 64 x 64 image covering exactly its
    20 x 15 m footprint, north up. Inline (referencePoint and orientation), each quarter of the
    image lands on its quarter of the roof. A world file beside the image wins over an inline
    georeference that is wrong (preferWorldFile, by default true), and loses to it where
    preferWorldFile is false. One whose orientation has no inverse is refused naming it; one
    with no georeference at all is said and not drawn."""
    _quadrant_image(tmp_path)
    (x0, y0), _, (x1, y1), _ = ROOF
    a, e = (x1 - x0) / 64, -(y1 - y0) / 64
    right = _inline(x0 + a / 2, y1 + e / 2, a, e)
    wrong = _inline(x0 + a / 2 + 10.0, y1 + e / 2, a, e)  # 10 m east: half the roof off
    frame = _frame()

    def city_with(member: str):
        path = write_citygml(tmp_path / "roof.gml", BUILDINGS, "EPSG:32632+3855")
        path.write_text(path.read_text().replace("</core:CityModel>", member + "</core:CityModel>"))
        return read_city(path, frame)

    city = city_with(_georeferenced("appearances/wall.png", right))
    assert sum(p.textured for p in city.mesh.primitives) == 1
    _check_roof_quadrants(city, frame, gl_ctx)
    feature = city.mesh.feature_at(_expected_enu(frame, x0 + 1.0, y0 + 1.0, 112.0))
    assert feature is not None and (feature.id, feature.surface) == ("A", "roof")

    (tmp_path / "appearances" / "wall.pgw").write_text(
        f"{a}\n0\n0\n{e}\n{x0 + a / 2}\n{y1 + e / 2}\n"
    )
    _check_roof_quadrants(city_with(_georeferenced("appearances/wall.png", wrong)), frame, gl_ctx)
    off = city_with(
        _georeferenced(
            "appearances/wall.png", wrong, "<app:preferWorldFile>false</app:preferWorldFile>"
        )
    )
    with pytest.raises(AssertionError):
        _check_roof_quadrants(off, frame, gl_ctx)

    (tmp_path / "appearances" / "wall.pgw").unlink()
    with pytest.raises(SceneError, match=r"GeoreferencedTexture appearances/wall.png.*inverse"):
        city_with(_georeferenced("appearances/wall.png", _inline(x0, y1, 0.0, 0.0)))
    bare = city_with(_georeferenced("appearances/wall.png", ""))
    assert not any(p.textured for p in bare.mesh.primitives)
    assert any(
        "GeoreferencedTexture appearances/wall.png" in m and "not drawn" in m
        for m in bare.notes.items
    )


def test_a_geotiffs_own_georeference_lays_its_texture(tmp_path, gl_ctx):
    """The roof's four-colour image as a GeoTIFF whose tags hold its georeference (UTM 32N, as the
    file's coordinates): laid by them over a wrong inline georeference (preferWorldFile, by
    default true), each quarter on its quarter of the roof. The same image georeferenced in
    UTM 33N is refused naming both CRSs; one with no georeference and nothing inline is said and
    not drawn."""
    _quadrant_image(tmp_path)
    rgb = np.asarray(Image.open(tmp_path / "appearances" / "wall.png").convert("RGB"))
    (x0, y0), _, (x1, y1), _ = ROOF
    a, e = (x1 - x0) / 64, -(y1 - y0) / 64
    wrong = _inline(x0 + a / 2 + 10.0, y1 + e / 2, a, e)
    frame = _frame()

    def geotiff(name: str, crs: str | None) -> str:
        tags = {"crs": crs, "transform": from_origin(x0, y1, a, -e)} if crs else {}
        with rasterio.open(
            tmp_path / "appearances" / name, "w", driver="GTiff", width=64, height=64, count=3,
            dtype="uint8", **tags,
        ) as dst:  # fmt: skip
            dst.write(rgb.transpose(2, 0, 1))
        return f"appearances/{name}"

    def city_with(member: str):
        path = write_citygml(tmp_path / "roof.gml", BUILDINGS, "EPSG:32632+3855")
        path.write_text(path.read_text().replace("</core:CityModel>", member + "</core:CityModel>"))
        return read_city(path, frame)

    city = city_with(_georeferenced(geotiff("roof.tif", "EPSG:32632"), wrong))
    assert sum(p.textured for p in city.mesh.primitives) == 1
    _check_roof_quadrants(city, frame, gl_ctx)
    with pytest.raises(SceneError, match=r"roof33.tif.*UTM zone 33N.*UTM zone 32N"):
        city_with(_georeferenced(geotiff("roof33.tif", "EPSG:32633"), wrong))
    bare = city_with(_georeferenced(geotiff("plain.tif", None), ""))
    assert not any(p.textured for p in bare.mesh.primitives)
    assert any("plain.tif" in m and "no georeference in it" in m for m in bare.notes.items)


def test_an_appearance_theme_is_a_city_models_key(tmp_path):
    """`theme` under a scene that is not a city model is refused, naming the field."""
    manifest = tmp_path / "session.toml"
    manifest.write_text(
        sample_manifest_text().replace('up_axis = "Y"', 'up_axis = "Y"\ntheme = "x"')
    )
    with pytest.raises(ManifestError, match=r"scene.theme.*city model's key"):
        read_config(manifest)
