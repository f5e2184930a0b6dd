"""Built-in scenes: sizes, materials, lights, clean geometry, closed solids, cameras."""

import warnings

import numpy as np
import pytest
import trimesh

from fovjax import scenes
from fovjax.scene import _atrium, _geometry
from fovjax.scene._cornell import LIGHT, TALL_BLOCK


def _build_quietly(builder, **kwargs):
    """Build a scene and fail on any warning (e.g. dropped zero-area triangles)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return builder(**kwargs)


@pytest.fixture(scope="module")
def small_atrium():
    return _build_quietly(scenes.atrium, triangles=20_000)


@pytest.fixture(scope="module")
def builtins(small_atrium):
    return {
        "spheres": _build_quietly(scenes.spheres),
        "cornell_box": _build_quietly(scenes.cornell_box),
        "cornell_mirror": _build_quietly(scenes.cornell_box, mirror_block=True, subdivisions=3),
        "atrium": small_atrium,
    }


NAMES = ["spheres", "cornell_box", "cornell_mirror", "atrium"]


@pytest.mark.parametrize("name", NAMES)
def test_builtin_is_well_formed(builtins, name):
    scene = builtins[name]
    v, f = np.asarray(scene.vertices), np.asarray(scene.faces)
    assert v.dtype == np.float32 and f.dtype == np.int32
    assert np.isfinite(v).all()
    assert f.min() >= 0 and f.max() < len(v)
    fm = np.asarray(scene.face_material)
    assert fm.shape == (len(f),) and fm.min() >= 0 and fm.max() < len(scene.materials)
    assert len(np.unique(fm)) == len(scene.materials), "every material is used"
    # no degenerate triangles: area well above zero relative to the scene's size
    tri = v[f].astype(np.float64)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    extent = np.ptp(v, axis=0).max()
    assert area.min() > 1e-8 * extent**2
    # at least one point light, finite, inside or above the scene's bounds
    assert len(scene.lights) >= 1
    assert np.isfinite(np.asarray(scene.lights.position)).all()
    assert (np.asarray(scene.lights.color) > 0).all()
    # shading normals: unit length, on the same side as each face's geometric normal
    n = np.asarray(scene.normals, np.float64)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    face_normal = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    assert (np.einsum("ij,ij->i", n[f].mean(axis=1), face_normal) > 0.5).all()


@pytest.mark.parametrize("name", NAMES)
def test_content_hash_is_deterministic(builtins, name):
    builder, kwargs = {
        "spheres": (scenes.spheres, {}),
        "cornell_box": (scenes.cornell_box, {}),
        "cornell_mirror": (scenes.cornell_box, {"mirror_block": True, "subdivisions": 3}),
        "atrium": (scenes.atrium, {"triangles": 20_000}),
    }[name]
    again = builder(**kwargs)
    assert again.content_hash == builtins[name].content_hash
    assert len(again.content_hash) == 64
    np.testing.assert_array_equal(np.asarray(again.vertices), np.asarray(builtins[name].vertices))


def test_hash_changes_with_geometry(builtins):
    hashes = {scene.content_hash for scene in builtins.values()}
    assert len(hashes) == len(builtins)
    assert scenes.spheres(subdivisions=2).content_hash != builtins["spheres"].content_hash


# --- atrium --------------------------------------------------------------------------------------


@pytest.mark.parametrize("triangles", [8_000, 20_000, 33_333, 60_000])
def test_atrium_size_follows_the_request(triangles):
    edge, floor_cells = _atrium._tessellation(triangles)
    plan = _atrium._plan(edge, floor_cells)
    planned = sum(p[3] for p in plan)
    assert abs(planned - triangles) <= 0.05 * triangles
    if triangles == 33_333:  # the plan's counts are what the builders make
        assert scenes.atrium(triangles=triangles).num_triangles == planned


def test_atrium_default_size_and_extent():
    scene = _build_quietly(scenes.atrium)
    assert abs(scene.num_triangles - 262_000) <= 0.01 * 262_000
    lo, hi = scene.bounds
    np.testing.assert_allclose(hi - lo, [30.0, 15.0, 13.0], atol=1e-4)  # Sponza-like, y up
    assert lo[1] == 0.0


def test_atrium_tessellation_scales(small_atrium):
    bigger = scenes.atrium(triangles=60_000)
    assert bigger.num_triangles > 2.5 * small_atrium.num_triangles
    np.testing.assert_allclose(bigger.bounds, small_atrium.bounds, atol=1e-5)


def test_atrium_too_small_is_an_error():
    with pytest.raises(ValueError, match="atrium: triangles=100 is below"):
        scenes.atrium(triangles=100)


def test_atrium_materials_and_light(small_atrium):
    m = small_atrium.materials
    names = list(m.names)
    kd, kr = np.asarray(m.kd), np.asarray(m.kr)
    assert {"floor_polished", "column_polished", "cloth_red", "cloth_green", "cloth_blue"} <= set(names)
    assert (kr > 0).any(axis=1).sum() >= 2, "a few reflective surfaces"
    for name, channel in (("cloth_red", 0), ("cloth_green", 1), ("cloth_blue", 2)):
        assert np.argmax(kd[names.index(name)]) == channel
    np.testing.assert_allclose(np.asarray(small_atrium.lights.position), [[0.0, 12.0, 0.0]])
    np.testing.assert_allclose(np.asarray(small_atrium.lights.color), [[0.7, 0.7, 0.7]], rtol=1e-6)
    # the reflective strip is on the floor, in the court
    fm = np.asarray(small_atrium.face_material)
    strip = np.asarray(small_atrium.triangles())[fm == names.index("floor_polished")]
    assert np.allclose(strip[..., 1], 0.0) and np.abs(strip[..., 2]).max() < 2.0


def test_atrium_solids_are_closed():
    """Every primitive the atrium plans as a solid is watertight with outward normals."""
    closed = {_geometry.add_box, _geometry.add_cylinder, _geometry.add_arch_bay}
    checked = {add: 0 for add in closed}
    for add, args, kwargs, count in _atrium._plan(0.6):
        if add not in closed:
            continue
        checked[add] += 1
        mb = _geometry.MeshBuilder()
        add(mb, *args, **kwargs)
        v, f, _, _ = mb.build()
        assert len(f) == count
        mesh = trimesh.Trimesh(v, f, process=False)
        mesh.merge_vertices(digits_vertex=12)  # vertices on shared edges are bit-identical
        assert mesh.is_watertight, add.__name__
        assert mesh.is_winding_consistent, add.__name__
        assert mesh.volume > 0, add.__name__
    assert min(checked.values()) >= 40  # boxes, column shafts and arch bays all checked


def test_arch_bay_volume_matches_its_profile():
    mb = _geometry.MeshBuilder()
    _geometry.add_arch_bay(mb, _geometry.ArchBay(0.0, 1.5, 1.1, 3.4, 5.2, -0.35, 0.35, 64, 2, 1), 0)
    v, f, _, _ = mb.build()
    mesh = trimesh.Trimesh(v, f, process=False)
    mesh.merge_vertices(digits_vertex=12)
    exact = (3.0 * 1.8 - np.pi * 1.1**2 / 2) * 0.7
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(exact, rel=2e-3)


# --- Cornell box ---------------------------------------------------------------------------------


def test_cornell_box_published_dimensions(builtins):
    scene = builtins["cornell_box"]
    assert scene.num_triangles == 32
    lo, hi = scene.bounds
    np.testing.assert_allclose(lo, [0, 0, 0], atol=1e-7)
    np.testing.assert_allclose(hi, [0.556, 0.5488, 0.5592], atol=1e-6)
    names = list(scene.materials.names)
    tri = np.asarray(scene.triangles())
    fm = np.asarray(scene.face_material)
    assert tri[fm == names.index("red")][..., 0].min() > 0.549  # the left wall, x ~ 0.55
    np.testing.assert_allclose(tri[fm == names.index("green")][..., 0], 0.0)  # the right wall
    np.testing.assert_allclose(tri[fm == names.index("tall_block")][..., 1].max(), 0.33, atol=1e-6)
    np.testing.assert_allclose(tri[fm == names.index("short_block")][..., 1].max(), 0.165, atol=1e-6)
    light = np.asarray(scene.lights.position)[0]
    np.testing.assert_allclose(light, [0.278, 0.5388, 0.2795], atol=1e-6)
    patch = tri[fm == names.index("light")]
    np.testing.assert_allclose(patch[..., 1], 0.5478, atol=1e-6)
    assert np.asarray(scene.materials.ke)[names.index("light")].max() > 0
    np.testing.assert_allclose(np.sort(np.unique(patch[..., 0])), [0.213, 0.343], atol=1e-6)


def test_cornell_box_in_millimetres_matches_the_data():
    scene = scenes.cornell_box(units="mm")
    names = list(scene.materials.names)
    tri = np.asarray(scene.triangles())
    tall = tri[np.asarray(scene.face_material) == names.index("tall_block")].reshape(-1, 3)
    published = np.asarray(TALL_BLOCK).reshape(-1, 3)
    assert {tuple(p) for p in np.round(tall, 3)} == {tuple(p) for p in published}
    assert np.asarray(LIGHT)[:, 1].max() == 548.8


def test_cornell_mirror_block(builtins):
    scene = builtins["cornell_mirror"]
    assert scene.num_triangles == 32 * 9
    m = scene.materials
    tall = list(m.names).index("tall_block")
    assert np.asarray(m.kr)[tall].min() > 0.9
    plain = scenes.cornell_box()
    assert np.asarray(plain.materials.kr).max() == 0.0


def test_cornell_box_rejects_bad_arguments():
    with pytest.raises(ValueError, match="units"):
        scenes.cornell_box(units="inch")
    with pytest.raises(ValueError, match="subdivisions"):
        scenes.cornell_box(subdivisions=0)


# --- spheres -------------------------------------------------------------------------------------


def test_spheres_size_and_materials(builtins):
    scene = builtins["spheres"]
    assert scene.num_triangles == 4 * 1280 + 2 * 64
    assert scenes.spheres(subdivisions=1).num_triangles == 4 * 80 + 2 * 64
    kr = np.asarray(scene.materials.kr)
    assert (kr.max(axis=1) > 0.5).sum() == 1, "one mirror sphere"
    assert scene.bounds[0][1] == 0.0
    with pytest.raises(ValueError, match="subdivisions"):
        scenes.spheres(subdivisions=-1)


# --- default cameras -----------------------------------------------------------------------------


def _first_hit_distance(scene, camera):
    mesh = trimesh.Trimesh(np.asarray(scene.vertices, np.float64), np.asarray(scene.faces), process=False)
    origin = np.asarray([camera.position])
    direction = np.asarray([camera.look_at]) - origin
    direction /= np.linalg.norm(direction)
    locations, _, _ = mesh.ray.intersects_location(origin, direction, multiple_hits=False)
    assert len(locations) == 1, "the camera looks at something"
    return float(np.linalg.norm(locations[0] - origin[0]))


def test_default_cameras(builtins):
    atrium_cam = scenes.default_camera(builtins["atrium"])
    lo, hi = builtins["atrium"].bounds
    assert (np.asarray(atrium_cam.position) > lo).all() and (np.asarray(atrium_cam.position) < hi).all()
    assert abs(atrium_cam.position[2]) < 3.0, "stands in the court"
    assert _first_hit_distance(builtins["atrium"], atrium_cam) > 20.0, "looks along the court"

    cornell_cam = scenes.default_camera(builtins["cornell_box"])
    np.testing.assert_allclose(cornell_cam.position, [0.278, 0.273, -0.8])
    assert cornell_cam.vfov_deg == pytest.approx(39.3076, abs=1e-3)
    # the view axis (x = 278 mm) meets the tall block's front face, (265, 296)-(423, 247) mm in x, z
    z_face = 296.0 + (278.0 - 265.0) * (247.0 - 296.0) / (423.0 - 265.0)
    assert _first_hit_distance(builtins["cornell_box"], cornell_cam) == pytest.approx(
        0.8 + z_face / 1000, abs=1e-5
    )
    mm = scenes.default_camera(scenes.cornell_box(units="mm"))
    np.testing.assert_allclose(mm.position, [278.0, 273.0, -800.0])

    spheres_cam = scenes.default_camera("spheres")
    assert _first_hit_distance(builtins["spheres"], spheres_cam) < 10.0

    with pytest.raises(ValueError, match="no built-in scene"):
        scenes.default_camera("sponza")


def test_generic_camera_sees_a_loaded_scene(builtins):
    import dataclasses

    scene = dataclasses.replace(builtins["spheres"], name="something_else")
    camera = scenes.default_camera(scene)
    lo, hi = scene.bounds
    assert camera.position[2] > hi[2]
    _first_hit_distance(scene, scenes.CameraPose(camera.position, (0.0, 1.0, -0.6)))


def test_camera_pose_validates():
    with pytest.raises(ValueError, match="coincide"):
        scenes.CameraPose((0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="parallel"):
        scenes.CameraPose((0, 0, 0), (0, 1, 0))
    with pytest.raises(ValueError, match="vfov"):
        scenes.CameraPose((0, 0, 0), (0, 0, 1), vfov_deg=180)
