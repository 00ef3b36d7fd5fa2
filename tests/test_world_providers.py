"""Where a world's sources come from and how they are credited (issue 48): well-known providers
by name from xyzservices' catalogue (their templates, levels, attribution and keys), `geofuse
cache --providers` and its bulk refusals; the default open sources used with nothing configured,
pointed at a loopback server here (and the flat ground, said, where it does not answer); the
credit written into the exports that carry a world's imagery. No test reaches the internet:
the defaults are replaced through GEOFUSE_DEFAULT_IMAGERY/TERRAIN, and every other test runs
with GEOFUSE_WORLD=none."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import numpy as np
import pytest
import rasterio
import xyzservices.providers as xyz
from PIL import Image

from app.cli import main
from app.core.errors import GeofuseError
from app.core.imageio import write_rgb
from app.export.orthophoto import write_orthophoto
from app.export.painted import painted_glb
from app.export.painted_tiles import write_painted_tiles
from app.geodesy.enu import LocalFrame
from app.scene.layers import Layer, scene_credit
from app.scene.tiles.gltf import split_glb
from app.ui.credit import wrap
from app.world import defaults, providers
from app.world.settings import choose_world, default_world, world_of
from app.world.sources import MAX_ZOOM, parse_source
from tests import test_world
from tests.conftest import run_viewer
from tests.test_ortho import _memory
from tests.test_world import (
    _own_folders,  # noqa: F401 (autouse: the test's own settings, cache and no default world)
)

clip = test_world.drone_clip  # a fixture: a 4 s DJI clip over the synthetic world
tiles = test_world.server  # a fixture: the synthetic world's tiles on the loopback

SECRET = "pr0vider-K3y-9876"


def test_a_provider_named_takes_its_template_levels_and_credit_from_xyzservices():
    topo = parse_source("OpenTopoMap", "imagery")
    want = xyz.OpenTopoMap
    # {s} filled with its first subdomain, as xyzservices builds it; the rest left for tiles
    assert topo.location == want.build_url() == "https://a.tile.opentopomap.org/{z}/{x}/{y}.png"
    assert topo.max_zoom == want["max_zoom"] == 17 and topo.attribution == want["attribution"]
    assert topo.url(12, 2145, 1434) == "https://a.tile.opentopomap.org/12/2145/1434.png"
    # case, dots and spaces aside; a provider without levels keeps the kind's own
    esri = parse_source("esri worldimagery", "imagery")
    assert esri.attribution.startswith("Tiles (C) Esri") and esri.max_zoom == MAX_ZOOM["imagery"]
    assert "{z}/{y}/{x}" in esri.location  # ArcGIS's row before column, as its template says
    # a terrain provider of the small table: its encoding and datum with it
    terrain = parse_source("AWS.Terrarium", "terrain")
    assert (terrain.encoding, terrain.datum, terrain.max_zoom) == ("terrarium", "egm96", 15)
    assert "U.S. Geological Survey" in terrain.attribution
    with pytest.raises(GeofuseError, match="it is terrain"):
        parse_source("AWS.Terrarium", "imagery")
    with pytest.raises(GeofuseError, match="it is imagery"):
        parse_source("OpenTopoMap", "terrain")
    # files and URLs are never taken for names; an unknown name is no provider
    assert providers.find("world.mbtiles") is None and providers.find("Nowhere.AtAll") is None
    assert providers.find("https://x/{z}/{x}/{y}.png") is None


def test_a_providers_key_comes_from_its_variable_or_the_settings_and_is_never_shown(monkeypatch):
    monkeypatch.delenv("MAPTILER_KEY", raising=False)
    with pytest.raises(GeofuseError, match="MAPTILER_KEY"):
        parse_source("MapTiler.Satellite", "imagery")
    monkeypatch.setenv("MAPTILER_KEY", SECRET)
    sat = parse_source("MapTiler.Satellite", "imagery")
    assert sat.url(3, 4, 2).endswith(f"/3/4/2.jpg?key={SECRET}")
    for shown in (sat.label, sat.identity, repr(sat), sat.redact(sat.url(3, 4, 2))):
        assert SECRET not in shown
    # a [[world]] table naming the provider: its own key_env, its attribution from the catalogue
    monkeypatch.setenv("OTHER_KEY", "other-" + SECRET)
    world = world_of({"name": "mt", "imagery": "MapTiler.Satellite", "key_env": "OTHER_KEY"})
    assert world.imagery.key == "other-" + SECRET
    assert world.credit == xyz.MapTiler.Satellite["attribution"]
    # a one-off --imagery by name credits its provider, --terrain's beside it
    monkeypatch.delenv("GEOFUSE_WORLD")
    one_off = choose_world(imagery="OpenTopoMap", terrain="AWS.Terrarium")
    assert one_off.credit == "; ".join(
        [xyz.OpenTopoMap["attribution"], providers.AWS_TERRAIN_CREDIT]
    )


def test_cache_lists_providers_and_refuses_bulk_download_where_their_terms_forbid_it(capsys):
    assert main(["cache", "--providers", "OpenStreetMap.Mapnik"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert line.startswith("OpenStreetMap.Mapnik ") and "no bulk download" in line
    assert "(C) OpenStreetMap contributors" in line
    assert main(["cache", "--providers", "terrarium"]) == 0
    assert "used with nothing configured" in capsys.readouterr().out
    # refused before anything is asked of the network
    for name, why in (("OpenStreetMap.Mapnik", "forbid bulk"), ("Esri.WorldImagery", "Esri's")):
        assert main(["cache", "--bbox", "7,46,7.01,46.01", "--imagery", name]) == 2
        assert why in capsys.readouterr().err


def test_the_default_sources_are_open_keyless_providers_replaceable_by_the_environment(
    monkeypatch,
):
    world = default_world()
    assert world.imagery.location.startswith("https://tiles.maps.eox.at/")
    assert (world.terrain.encoding, world.imagery.key, world.terrain.key) == (
        "terrarium",
        None,
        None,
    )
    assert world.credit == f"{providers.EOX_2016_CREDIT}; {providers.AWS_TERRAIN_CREDIT}"
    monkeypatch.setenv(defaults.ENV_TERRAIN, "none")
    monkeypatch.setenv(defaults.ENV_IMAGERY, "OpenTopoMap")
    assert default_world().terrain is None and default_world().imagery.max_zoom == 17
    monkeypatch.setenv(defaults.ENV_IMAGERY, "no such thing")
    with pytest.raises(GeofuseError, match=defaults.ENV_IMAGERY):
        default_world()


def _defaults_at(monkeypatch, base: str) -> None:
    """Nothing configured, the default imagery replaced by the loopback server's tiles (no
    terrain: a DEM mesh of the default's levels takes seconds to build, for nothing more)."""
    monkeypatch.delenv("GEOFUSE_WORLD")
    monkeypatch.setenv(defaults.ENV_IMAGERY, f"{base}/img/{{z}}/{{x}}/{{y}}.png")
    monkeypatch.setenv(defaults.ENV_TERRAIN, "none")


def test_nothing_configured_drapes_a_clip_on_the_default_sources_where_they_answer(
    tiles, clip, tmp_path, monkeypatch, capsys
):
    _defaults_at(monkeypatch, tiles.base)
    world = choose_world()
    assert world.name == defaults.NAME and world.probe_s == defaults.PROBE_TIMEOUT_S
    assert choose_world(scene_named=True) is None  # a scene named: no world unless asked
    out = tmp_path / "poses.csv"
    assert main(["solve", str(clip), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "world open: nothing configured, so the default open sources (127.0.0.1" in err
    assert "world open imagery" in err and "world open has no terrain source" in err
    assert "the video is projected on an assumed flat ground" not in err
    asked = len(tiles.log)
    assert asked > 0
    assert main(["solve", str(clip), "--out", str(out), "--world", "none"]) == 0
    assert "assumed flat ground" in capsys.readouterr().err and len(tiles.log) == asked


def test_default_sources_that_do_not_answer_leave_the_flat_ground_and_say_how_to_configure(
    tiles, clip, tmp_path, monkeypatch, capsys
):
    tiles.stop()  # nothing listens there any more: refused at once
    _defaults_at(monkeypatch, tiles.base)
    assert main(["solve", str(clip), "--out", str(tmp_path / "poses.csv")]) == 0
    err = capsys.readouterr().err
    assert f"did not answer within {defaults.PROBE_TIMEOUT_S:g} s" in err
    assert "assumed flat ground" in err and "[[world]]" in err and "--providers" in err


def test_the_probe_gives_up_on_a_server_that_never_answers():
    with socket.socket() as silent:  # accepts connections (the backlog) and never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        url = f"http://127.0.0.1:{silent.getsockname()[1]}/{{z}}/{{x}}/{{y}}.png"
        assert defaults.network_answers([url], timeout_s=0.3) is False
    assert defaults.network_answers(["/a/local/file.mbtiles"], timeout_s=0.3) is True


def test_the_credit_of_a_scene_is_written_into_the_exports_that_carry_its_imagery(tmp_path):
    layers = (
        Layer("world:open", "world", attribution="(c) Imagery A; Heights B"),
        Layer("b.osm", "city", attribution="(c) OpenStreetMap contributors; Heights B"),
        Layer("model.glb", "mesh"),
    )
    credit = scene_credit(layers)
    assert credit == "(c) Imagery A; Heights B; (c) OpenStreetMap contributors"
    # the orthophoto COG: TIFF Copyright and an ATTRIBUTION item (its seen-at bands carry none)
    out, seen = write_orthophoto(_memory(gsd=2.0), tmp_path / "ortho.tif", [], credit)
    with rasterio.open(out) as src:
        tags = src.tags()
        assert tags["TIFFTAG_COPYRIGHT"] == credit and tags["ATTRIBUTION"] == credit
    with rasterio.open(seen) as src:
        assert "ATTRIBUTION" not in src.tags()
    # the painted GLB and a painted tileset's tiles: glTF asset.copyright
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    uvs = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    image = np.full((2, 2, 3), 200, np.uint8)
    doc, _ = split_glb(painted_glb([(tri, uvs, image)], (46.0, 7.0, 600.0), credit))
    assert doc["asset"]["copyright"] == credit
    assert (
        "copyright" not in split_glb(painted_glb([(tri, uvs, image)], (46.0, 7.0, 0.0)))[0]["asset"]
    )
    tileset, n = write_painted_tiles(
        [(tri, uvs, image)],
        LocalFrame(46.0, 7.0, 600.0),
        tmp_path / "t" / "tileset.json",
        [],
        credit,
    )
    tile = split_glb((tileset.parent / "tileset_0.glb").read_bytes())[0]
    assert n == 1 and tile["asset"]["copyright"] == credit
    # a still (render --session): PNG Copyright text, JPEG EXIF Copyright
    png = write_rgb(tmp_path / "still.png", image, credit=credit)
    with Image.open(png) as img:
        assert img.text["Copyright"] == credit
    jpg = write_rgb(tmp_path / "still.jpg", image, credit=credit)
    with Image.open(jpg) as img:
        assert img.getexif()[0x8298] == credit


def _credited_world(tiles, tmp_path: Path) -> None:
    """A settings file naming `credited`: the loopback server's imagery (to zoom 14: a few tiles,
    no terrain to mesh) with its attribution."""
    folder = tmp_path / "config" / "geofuse"
    folder.mkdir(parents=True)
    (folder / "settings.toml").write_text(
        f'[[world]]\nname = "credited"\nimagery = "{tiles.base}/img/{{z}}/{{x}}/{{y}}.png"\n'
        'imagery_max_zoom = 14\nattribution = "(c) Test imagery"\n'
    )


def test_a_still_rendered_on_a_world_carries_its_credit(tiles, clip, tmp_path):
    _credited_world(tiles, tmp_path)
    out = tmp_path / "still.png"
    args = ["render", "--session", str(clip), "--time", "1", "--size", "160x90", "--out", str(out)]
    assert main([*args, "--world", "credited"]) == 0
    with Image.open(out) as img:
        assert img.text["Copyright"] == "(c) Test imagery"
    assert main([*args, "--world", "none"]) == 0  # nothing to credit on the flat ground
    with Image.open(out) as img:
        assert "Copyright" not in img.text


def test_a_long_credit_wraps_between_words_within_the_view():
    width = lambda s: 7.0 * len(s)  # noqa: E731 (a monospaced font, 7 px a character)
    lines = wrap("Tiles (C) Esri -- Source: Esri, i-cubed, USDA, USGS", 20 * 7.0, width)
    assert lines == ["Tiles (C) Esri --", "Source: Esri,", "i-cubed, USDA, USGS"]
    assert all(width(s) <= 140.0 for s in lines)
    assert wrap("Averyveryverylongword x", 35.0, width) == ["Averyveryverylongword", "x"]


def _corner(shot: Path, rect: list[int], up: int = 0) -> np.ndarray:
    """The bottom-right 160 x 20 pixels (RGB) of the 3D view `rect` (x, y from the top, w, h)
    in a screenshot, `up` pixels higher."""
    x, y, w, h = rect
    img = np.asarray(Image.open(shot).convert("RGB"), int)
    return img[y + h - 20 - up : y + h - up, x + w - 160 : x + w]


@pytest.mark.gl
def test_the_viewer_shows_the_worlds_credit_over_the_3d_view_panels_or_not(
    display, tiles, clip, tmp_path
):
    _credited_world(tiles, tmp_path)
    bare, paneled = tmp_path / "bare.png", tmp_path / "paneled.png"
    script = tmp_path / "script.txt"
    script.write_text(
        f"""0.0 clock 0.0333333
0.0 panels off
0.0 lines off
0.0 project off
0.0 wait world
0.1 state {tmp_path / "bare.json"}
0.1 screenshot {bare}
0.2 panels on
0.4 state {tmp_path / "paneled.json"}
0.4 screenshot {paneled}
0.5 quit
"""
    )
    run = run_viewer(
        display, str(clip), "--world", "credited", "--script", str(script), "--size", "640x360",
        config_home=tmp_path / "config",
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    for name, shot in (("bare", bare), ("paneled", paneled)):
        state = json.loads((tmp_path / f"{name}.json").read_text())
        assert state["world"]["shown"] == "full" and state["errors"] == []
        assert state["credit"] == "(c) Test imagery"
        # white text on a darkened band, where the imagery (blue 140 at zoom 14) is never white
        band, above = _corner(shot, state["view_rect"]), _corner(shot, state["view_rect"], 40)
        assert (band.min(axis=2) > 200).sum() >= 20 and (above.min(axis=2) > 200).sum() == 0
        assert np.median(band.sum(axis=2)) < 0.6 * np.median(above.sum(axis=2)), name
