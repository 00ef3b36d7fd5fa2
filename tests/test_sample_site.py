import hashlib

import numpy as np
import pytest

from app.geodesy.enu import LocalFrame
from app.scene import load_scene
from app.simulate.sample import SAMPLE_SCENE
from app.simulate.stadium import BUILDINGS, HALL_MAX, HALL_MIN, SITE_ORIGIN, write_site


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    path = tmp_path_factory.mktemp("site") / "scene.glb"
    write_site(path)
    return path


def test_generation_is_reproducible_and_matches_the_committed_sample(site, tmp_path):
    again = write_site(tmp_path / "again.glb")
    digest = hashlib.sha256(site.read_bytes()).hexdigest()
    assert hashlib.sha256(again.read_bytes()).hexdigest() == digest
    assert hashlib.sha256(SAMPLE_SCENE.read_bytes()).hexdigest() == digest, (
        "assets/sample/scene.glb is stale: regenerate it"
    )
    assert site.stat().st_size < 4e6


def test_hall_and_buildings_have_the_stated_size(site):
    mesh = load_scene(site, LocalFrame(*SITE_ORIGIN))
    hall = next(p for p in mesh.primitives if p.name == "hall_walls")
    lo, hi = hall.positions.min(axis=0), hall.positions.max(axis=0)
    np.testing.assert_allclose(hi - lo, [90.0, 81.0, 20.0], atol=1e-4)
    np.testing.assert_allclose(lo, HALL_MIN, atol=1e-4)
    np.testing.assert_allclose(hi, HALL_MAX, atol=1e-4)
    assert 3 <= len(BUILDINGS) <= 6
    assert len({b.max_corner[2] for b in BUILDINGS}) == len(BUILDINGS)  # all different heights
    textured = {p.name for p in mesh.primitives if p.textured}
    assert {"ground", "hall_walls", "hall_roof"} | {
        f"building_{b.name}" for b in BUILDINGS
    } <= textured
    assert SITE_ORIGIN[0] == pytest.approx(34.80, abs=0.01) and SITE_ORIGIN[1] == pytest.approx(
        113.53, abs=0.01
    )
