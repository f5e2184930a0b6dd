"""`load_scene`: OBJ+MTL, glTF/GLB and PLY round trips, and every bad-input case."""

import json
import os
import re
import warnings
from pathlib import Path

import equinox as eqx
import numpy as np
import pytest
import trimesh
from PIL import Image

import fovjax
from fovjax.scene._parts import srgb_to_linear

# A unit square in z = 0 (a quad, material "red") and a triangle in z = 1 (material "blue").
OBJ = """\
# two materials, texture coordinates, normals
mtllib scene.mtl
o square
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 0 1 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
vn 0 0.6 0.8
usemtl red
f 1/1/1 2/2/1 3/3/1 4/4/1
usemtl blue
f 5/1/2 6/2/2 7/4/2
"""

MTL = """\
newmtl red
Ka 0.1 0.0 0.0
Kd 0.8 0.1 0.05
Ks 0.5 0.5 0.5
Ke 0.0 0.2 0.0
Ns 64
Kr 0.25
illum 2
map_Kd -s 1 1 1 -o 0 0 tex.png

newmtl blue
Kd 0.1 0.2 0.9
Ks 0.3 0.4 0.5
Ns 200
illum 3
"""

# 2 x 2 sRGB texture, top row first as in the file
TEXTURE = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [128, 128, 128]]], np.uint8)


def write_obj(tmp_path, obj=OBJ, mtl=MTL, texture=True, name="scene.obj"):
    (tmp_path / name).write_text(obj)
    if mtl is not None:
        (tmp_path / "scene.mtl").write_text(mtl)
    if texture:
        Image.fromarray(TEXTURE).save(tmp_path / "tex.png")
    return tmp_path / name


def load_quietly(path, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fovjax.load_scene(path, **kwargs)


def material_of_faces(scene):
    names = np.asarray(scene.materials.names)
    return names[np.asarray(scene.face_material)]


# --- OBJ + MTL -----------------------------------------------------------------------------------


def test_obj_round_trip(tmp_path):
    scene = load_quietly(write_obj(tmp_path))
    assert scene.num_triangles == 3
    assert scene.name == "scene"
    tri = np.asarray(scene.triangles())
    per_face = material_of_faces(scene)
    # the quad (z = 0) is red and split into two triangles; the triangle (z = 1) is blue
    assert sorted(per_face.tolist()) == ["blue", "red", "red"]
    assert np.allclose(tri[per_face == "red"][..., 2], 0.0)
    assert np.allclose(tri[per_face == "blue"][..., 2], 1.0)
    red_area = sum(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) for t in tri[per_face == "red"])
    assert red_area == pytest.approx(1.0)

    m = scene.materials
    names = list(m.names)
    assert names == ["red", "blue"]  # in order of first use
    red, blue = names.index("red"), names.index("blue")
    np.testing.assert_allclose(np.asarray(m.ka)[red], [0.1, 0.0, 0.0])
    np.testing.assert_allclose(np.asarray(m.kd)[red], [0.8, 0.1, 0.05])
    np.testing.assert_allclose(np.asarray(m.ks)[red], [0.5, 0.5, 0.5])
    np.testing.assert_allclose(np.asarray(m.ke)[red], [0.0, 0.2, 0.0])
    np.testing.assert_allclose(np.asarray(m.kr)[red], [0.25, 0.25, 0.25])  # Kr
    assert float(np.asarray(m.ns)[red]) == 64.0
    # illum 3 ("reflection on, ray trace on"): reflects with the colour Ks
    np.testing.assert_allclose(np.asarray(m.kr)[blue], [0.3, 0.4, 0.5])
    assert float(np.asarray(m.ns)[blue]) == 200.0

    # texture: map_Kd with options, linear float32, row 0 = bottom row of the image (v = 0)
    assert int(np.asarray(m.texture)[red]) == 0 and int(np.asarray(m.texture)[blue]) == -1
    assert len(scene.textures) == 1 and scene.texture_paths == ("tex.png",)
    tex = scene.textures[0]
    assert tex.dtype == np.float32 and tex.shape == (2, 2, 3)
    np.testing.assert_allclose(tex, srgb_to_linear(TEXTURE[::-1] / 255.0), rtol=1e-6)
    assert tex[1, 0, 0] == 1.0 and tex[0, 1, 0] == pytest.approx(0.2158605, abs=1e-6)  # 128 -> linear

    # per-vertex texture coordinates and normals follow the face corners of the file
    v, f = np.asarray(scene.vertices), np.asarray(scene.faces)
    uv, n = np.asarray(scene.uvs), np.asarray(scene.normals)
    expected_uv = {(0, 0, 0): (0, 0), (1, 0, 0): (1, 0), (1, 1, 0): (1, 1), (0, 1, 0): (0, 1)}
    expected_uv |= {(0, 0, 1): (0, 0), (1, 0, 1): (1, 0), (0, 1, 1): (0, 1)}
    for i in np.unique(f):
        assert tuple(uv[i]) == expected_uv[tuple(v[i].tolist())]
        np.testing.assert_allclose(n[i], [0, 0, 1] if v[i][2] == 0 else [0, 0.6, 0.8], atol=1e-6)
    # no lights in an OBJ: one white point light at the default camera (a headlight)
    light = np.asarray(scene.lights.position)
    assert light.shape == (1, 3)
    np.testing.assert_allclose(light[0], fovjax.scenes.default_camera(scene).position, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(scene.lights.color), [[1.0, 1.0, 1.0]])


def test_a_closed_mesh_without_lights_or_materials_renders_lit(tmp_path):
    # A user's own closed mesh, OBJ without MTL (grey Kd 0.8, Ka 0): from the default camera,
    # nearly every pixel that sees the mesh is lit by the default light.
    from fovjax.render import MAGENTA, RenderConfig, render

    ball = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in ball.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in ball.faces]
    path = tmp_path / "ball.obj"
    path.write_text("\n".join(lines) + "\n")
    scene = load_quietly(path)
    pose = fovjax.scenes.default_camera(scene)
    camera = fovjax.Camera.look_at(
        pose.position, pose.look_at, pose.up, vfov_deg=pose.vfov_deg, width=24, height=24
    )
    config = RenderConfig(max_depth=0, background=MAGENTA)

    def lit_fraction(s):
        image = np.asarray(render(s, camera, config=config).image)
        seen = ~np.all(np.isclose(image, MAGENTA, atol=1e-3), axis=-1)  # rays that hit the ball
        assert 0.1 < seen.mean() < 0.9  # the ball is in view and does not fill it
        return float((image[seen].mean(axis=-1) > 0.05).mean())

    assert lit_fraction(scene) > 0.95
    # The former default, one light straight above the ball, leaves its lower half dark.
    above = eqx.tree_at(lambda t: t.lights, scene, fovjax.make_lights([[0.0, 1.2, 0.0]], [[1.0, 1.0, 1.0]]))
    assert lit_fraction(above) < 0.7


def test_obj_reflectivity_conventions(tmp_path):
    mtl = """\
newmtl a
Kd 1 1 1
refl 0.3
newmtl b
Kd 1 1 1
Ks 0.9 0.9 0.9
refl -type sphere chrome.png
illum 2
newmtl c
Kd 1 1 1
Ks 0.5 0.5 0.5
Kr 0.1 0.2 0.3
illum 3
"""
    obj = "mtllib scene.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
    obj += "usemtl a\nf 1 2 3\nusemtl b\nf 1 3 2\nusemtl c\nf 2 1 3\n"
    scene = load_quietly(write_obj(tmp_path, obj, mtl, texture=False))
    kr = dict(zip(scene.materials.names, np.asarray(scene.materials.kr).tolist(), strict=True))
    np.testing.assert_allclose(kr["a"], [0.3] * 3)  # scalar refl
    np.testing.assert_allclose(kr["b"], [0.0] * 3)  # a reflection map, and illum 2: no mirror
    np.testing.assert_allclose(kr["c"], [0.1, 0.2, 0.3])  # Kr wins over illum 3


def test_obj_relative_indices_and_polygons(tmp_path):
    absolute = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 0 0 2\nv 1 0 2\nv 1 1 2\nv 0 1 2\nf 4 5 6 7\n"
    relative = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 2\nv 1 0 2\nv 1 1 2\nv 0 1 2\nf -4 -3 -2 -1\n"
    a = load_quietly(write_obj(tmp_path, absolute, None, False, "a.obj"))
    b = load_quietly(write_obj(tmp_path, relative, None, False, "b.obj"))
    assert a.num_triangles == b.num_triangles == 3
    np.testing.assert_array_equal(np.asarray(a.triangles()), np.asarray(b.triangles()))
    assert a.materials.names == ("default",)
    assert a.normals is None and a.uvs is None  # the file has none


def test_obj_texture_shared_and_case_insensitive(tmp_path):
    mtl = "newmtl a\nmap_Kd TEX.PNG\nnewmtl b\nmap_Kd textures\\tex.png\n"
    (tmp_path / "textures").mkdir()
    Image.fromarray(TEXTURE).save(tmp_path / "textures" / "tex.png")
    Image.fromarray(TEXTURE).save(tmp_path / "tex.png")
    obj = "mtllib scene.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n"
    obj += "usemtl a\nf 1/1 2/1 3/1\nusemtl b\nf 1/1 3/1 2/1\n"
    scene = load_quietly(write_obj(tmp_path, obj, mtl, texture=False))
    assert np.asarray(scene.materials.texture).tolist() == [0, 1]
    assert len(scene.textures) == 2


def test_obj_scale_and_lights(tmp_path):
    lights = fovjax.make_lights([[0, 5, 0]], [[0.5, 0.5, 0.5]])
    scene = load_quietly(write_obj(tmp_path), scale=2.0, lights=lights, name="twice")
    assert scene.name == "twice"
    np.testing.assert_allclose(scene.bounds, [[0, 0, 0], [2, 2, 2]])
    np.testing.assert_allclose(np.asarray(scene.lights.position), [[0, 5, 0]])
    with pytest.raises(ValueError, match="scale"):
        fovjax.load_scene(write_obj(tmp_path), scale=0.0)


# --- glTF / GLB ----------------------------------------------------------------------------------


def _gltf_scene():
    image = Image.fromarray(TEXTURE)
    a = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    a.vertex_normals = [[0, 0, 1], [0, 0, 1], [0, 0, 1]]
    a.visual = trimesh.visual.TextureVisuals(
        uv=[[0, 0], [1, 0], [0, 1]],
        material=trimesh.visual.material.PBRMaterial(
            name="textured",
            baseColorFactor=[1.0, 0.6, 0.2, 1.0],
            metallicFactor=0.25,
            roughnessFactor=0.5,
            baseColorTexture=image,
        ),
    )
    b = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    b.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(
            name="metal", baseColorFactor=[0.2, 0.4, 0.8, 1.0], metallicFactor=1.0, roughnessFactor=0.0,
            emissiveFactor=[0.5, 0.0, 0.0],
        )
    )  # fmt: skip
    scene = trimesh.Scene()
    scene.add_geometry(a, node_name="a", geom_name="a")
    scene.add_geometry(
        b, node_name="b", geom_name="b", transform=trimesh.transformations.translation_matrix([0, 0, 5])
    )
    return scene


def _check_gltf(scene):
    assert scene.num_triangles == 3
    per_face = material_of_faces(scene)
    tri = np.asarray(scene.triangles())
    assert (per_face == "textured").sum() == 1 and (per_face == "metal").sum() == 2
    np.testing.assert_allclose(tri[per_face == "metal"][..., 2], 5.0)  # node transform applied
    np.testing.assert_allclose(tri[per_face == "textured"][..., 2], 0.0)
    m = scene.materials
    names = list(m.names)
    t, mt = names.index("textured"), names.index("metal")
    base = np.array([1.0, 0.6, 0.2])
    q = 1 / 255 + 1e-6  # trimesh stores baseColorFactor as 8-bit
    np.testing.assert_allclose(np.asarray(m.kd)[t], base * 0.75, atol=q)
    np.testing.assert_allclose(np.asarray(m.ks)[t], 0.04 * 0.75 + base * 0.25, atol=q)
    assert float(np.asarray(m.ns)[t]) == pytest.approx(2 / 0.5**4 - 2)
    np.testing.assert_allclose(np.asarray(m.kr)[t], (0.04 * 0.75 + base * 0.25) * 0.25, atol=q)
    np.testing.assert_allclose(np.asarray(m.kd)[mt], 0.0)
    np.testing.assert_allclose(np.asarray(m.ks)[mt], [0.2, 0.4, 0.8], atol=q)
    np.testing.assert_allclose(np.asarray(m.kr)[mt], [0.2, 0.4, 0.8], atol=q)  # smooth metal: a mirror
    assert float(np.asarray(m.ns)[mt]) == 1e4
    np.testing.assert_allclose(np.asarray(m.ke)[mt], [0.5, 0.0, 0.0])
    assert int(np.asarray(m.texture)[t]) == 0 and int(np.asarray(m.texture)[mt]) == -1
    np.testing.assert_allclose(scene.textures[0], srgb_to_linear(TEXTURE[::-1] / 255.0), rtol=1e-6)
    # UVs survive (trimesh flips glTF's v on export and on import)
    v, uv = np.asarray(scene.vertices), np.asarray(scene.uvs)
    textured = np.unique(np.asarray(scene.faces)[per_face == "textured"])
    lookup = {tuple(v[i].tolist()): tuple(uv[i].tolist()) for i in textured}
    assert lookup == {(0, 0, 0): (0, 0), (1, 0, 0): (1, 0), (0, 1, 0): (0, 1)}


def test_glb_round_trip(tmp_path):
    path = tmp_path / "scene.glb"
    _gltf_scene().export(path)
    _check_gltf(load_quietly(path))


def test_gltf_round_trip_with_external_buffers(tmp_path):
    files = trimesh.exchange.gltf.export_gltf(_gltf_scene())
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    _check_gltf(load_quietly(tmp_path / "model.gltf"))


def test_gltf_missing_texture_warns_and_falls_back(tmp_path):
    files = trimesh.exchange.gltf.export_gltf(_gltf_scene())
    header = json.loads(files.pop("model.gltf"))
    header["images"] = [{"uri": "missing_basecolor.png"}]
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    (tmp_path / "model.gltf").write_text(json.dumps(header))
    with pytest.warns(UserWarning, match=r"model\.gltf.*missing_basecolor\.png.*not found"):
        scene = fovjax.load_scene(tmp_path / "model.gltf")
    assert (np.asarray(scene.materials.texture) == -1).all()
    t = list(scene.materials.names).index("textured")
    np.testing.assert_allclose(np.asarray(scene.materials.kd)[t], [0.75, 0.45, 0.15], atol=1 / 255)


# --- PLY -----------------------------------------------------------------------------------------


def test_ply_round_trip(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    normals = np.asarray(mesh.vertex_normals)  # computing them puts them in the cache: exported
    path = tmp_path / "sphere.ply"
    mesh.export(path)
    scene = load_quietly(path)
    assert scene.num_triangles == 80
    np.testing.assert_allclose(np.asarray(scene.triangles()), mesh.triangles, atol=1e-6)
    np.testing.assert_allclose(np.asarray(scene.normals), normals, atol=1e-6)
    assert scene.materials.names == ("default",)


def _ascii_ply(vertices, faces):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x"]
    lines += ["property float y", "property float z", f"element face {len(faces)}"]
    lines += ["property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(str(x) for x in v) for v in vertices]
    lines += [f"{len(f)} " + " ".join(str(i) for i in f) for f in faces]
    return "\n".join(lines) + "\n"


def test_ply_face_index_out_of_range(tmp_path):
    path = tmp_path / "bad.ply"
    path.write_text(_ascii_ply([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2), (0, 2, 7)]))
    with pytest.raises(ValueError, match=r"bad\.ply: face 1 has vertex index \[0, 2, 7\] out of range for 3"):
        fovjax.load_scene(path)


def test_ply_nan_vertex(tmp_path):
    path = tmp_path / "nan.ply"
    path.write_text(_ascii_ply([(0, 0, 0), (1, "nan", 0), (0, 1, 0)], [(0, 1, 2)]))
    with pytest.raises(ValueError, match=r"nan\.ply: 1 vertices are NaN or infinite \(first: vertex 1"):
        fovjax.load_scene(path)


def test_ply_without_faces(tmp_path):
    path = tmp_path / "points.ply"
    trimesh.PointCloud(np.random.default_rng(0).random((5, 3))).export(path)
    with pytest.raises(ValueError, match=r"points\.ply: .*no faces"):
        fovjax.load_scene(path)


# --- bad input -----------------------------------------------------------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nowhere\.obj: scene file does not exist"):
        fovjax.load_scene(tmp_path / "nowhere.obj")


def test_a_folder_without_scene_files(tmp_path):
    (tmp_path / "dir.obj").mkdir()  # a folder is read as the scene files in it, whatever its name
    (tmp_path / "dir.obj" / "notes.txt").write_text("not a scene")
    with pytest.raises(FileNotFoundError, match=r"dir\.obj: the folder holds no scene file \(\.obj"):
        fovjax.load_scene(tmp_path / "dir.obj")


def test_unreadable_file(tmp_path):
    """A scene file that exists and cannot be read: one without read permission, or, for root
    (who reads any file), a link to Linux's /proc/self/mem, whose first page no process maps."""
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        path = write_obj(tmp_path)
        path.chmod(0)
    else:
        assert Path("/proc/self/mem").exists(), "as root, the test needs Linux's /proc"
        path = tmp_path / "scene.obj"
        path.symlink_to("/proc/self/mem")
    try:
        with pytest.raises(OSError, match=r"scene\.obj: cannot read scene file"):
            fovjax.load_scene(path)
    finally:
        if not path.is_symlink():
            path.chmod(0o644)


def test_unknown_format(tmp_path):
    path = tmp_path / "scene.xyz"
    path.write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"scene\.xyz: unknown scene format '\.xyz' \(supported: \.obj"):
        fovjax.load_scene(path)


@pytest.mark.parametrize(
    "body, message",
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", r"bad\.obj: no faces \('f' lines\) found"),
        ("f 1 2 3\n", r"bad\.obj: no vertices"),
        ("v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", r"bad\.obj:2: 'v' line has a NaN or infinite value"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 inf\nf 1 2 3\n", r"bad\.obj:3: 'v' line has a NaN or infinite value"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 nan\nf 1//1 2//1 3//1\n", r"bad\.obj:4: 'vn' line has a NaN"),
        ("v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n", r"bad\.obj:2: 'v' line has a value that is not a number"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n",
            r"bad\.obj:5: v index 9 out of range \(the file has 3",
        ),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", r"bad\.obj:4: v index 0 out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n", r"bad\.obj:5: vt index 2 out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//4\n", r"bad\.obj:5: vn index 4 out of range"),
        ("v 0 0 0\nf -1 -2 -3\nv 1 0 0\nv 0 1 0\n", r"bad\.obj:2: relative v index -2 reaches before"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", r"bad\.obj:4: a face needs at least 3 vertices"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", r"bad\.obj:4: face index 'x' is not an integer"),
        # A short vertex line: trimesh would shape the whole array by it (or shift the vertices
        # after it, when another line's extra number makes up the count) without a word.
        ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", r"bad\.obj:2: 'v' line needs at least 3 numbers: 'v 1 0'"),
        ("v 0 0 0\nv 1 0\nv 0 1 0 1\nf 1 2 3\n", r"bad\.obj:2: 'v' line needs at least 3 numbers"),
        ("v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n", r"bad\.obj:1: 'v' line needs at least 3 numbers"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 1\nf 1//1 2//1 3//1\n", r"bad\.obj:4: 'vn' line needs at least 3"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt\nf 1 2 3\n", r"bad\.obj:4: 'vt' line needs at least 1 number:"),
    ],
)
def test_obj_bad_input_names_the_line(tmp_path, body, message):
    path = tmp_path / "bad.obj"
    path.write_text(body)
    with pytest.raises(ValueError, match=message):
        fovjax.load_scene(path)


def test_obj_error_line_numbers_count_comments_and_mtllib(tmp_path):
    body = "# header\nmtllib scene.mtl\n\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\nf 1 2 4\n"
    path = write_obj(tmp_path, body, MTL)
    with pytest.raises(ValueError, match=r"scene\.obj:9: v index 4 out of range"):
        fovjax.load_scene(path)


def test_mtl_bad_number_names_the_line(tmp_path):
    path = write_obj(tmp_path, mtl=MTL.replace("Kd 0.1 0.2 0.9", "Kd 0.1 blue 0.9"))
    with pytest.raises(ValueError, match=r"scene\.mtl:12: Kd has a value that is not a number"):
        fovjax.load_scene(path)


def test_missing_mtl_warns_once_naming_the_line_and_uses_defaults(tmp_path):
    path = write_obj(tmp_path, mtl=None, texture=False)
    with pytest.warns(UserWarning) as record:
        scene = fovjax.load_scene(path)
    assert len(record) == 1, [str(w.message) for w in record]
    assert re.search(
        r"scene\.obj:2: material library 'scene\.mtl' not found .*materials \['red', 'blue'\] render "
        r"in the default grey",
        str(record[0].message),
    )
    assert scene.materials.names == ("default",)
    assert scene.num_triangles == 3


def test_materials_no_library_defines_warn_once(tmp_path):
    """An MTL file that is there but defines none of the materials used: said once."""
    path = write_obj(tmp_path, mtl="newmtl other\nKd 1 1 1\n", texture=False)
    with pytest.warns(UserWarning) as record:
        fovjax.load_scene(path)
    assert len(record) == 1
    assert re.search(
        r"materials \['red', 'blue'\] are used \(usemtl\) but no MTL file", str(record[0].message)
    )


def test_missing_texture_warns_and_falls_back_to_kd(tmp_path):
    path = write_obj(tmp_path, texture=False)
    with pytest.warns(
        UserWarning, match=r"scene\.mtl:9: texture file 'tex\.png' not found.*using Kd instead"
    ):
        scene = fovjax.load_scene(path)
    assert (np.asarray(scene.materials.texture) == -1).all()
    assert scene.textures == ()
    np.testing.assert_allclose(np.asarray(scene.materials.kd)[0], [0.8, 0.1, 0.05])


def test_corrupt_texture_warns(tmp_path):
    path = write_obj(tmp_path, texture=False)
    (tmp_path / "tex.png").write_bytes(b"not a png at all")
    with pytest.warns(UserWarning, match=r"scene\.mtl:9: cannot read texture .*tex\.png"):
        scene = fovjax.load_scene(path)
    assert (np.asarray(scene.materials.texture) == -1).all()


def test_zero_area_triangles_are_dropped_with_a_count(tmp_path):
    body = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 2 2 3\n"
    path = tmp_path / "flat.obj"
    path.write_text(body)
    with pytest.warns(UserWarning, match=r"flat\.obj: dropped 2 zero-area triangles of 3"):
        scene = fovjax.load_scene(path)
    assert scene.num_triangles == 1


def test_only_zero_area_triangles_is_an_error(tmp_path):
    path = tmp_path / "line.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with (
        pytest.raises(ValueError, match=r"line\.obj: every triangle has zero area"),
        warnings.catch_warnings(),
    ):
        warnings.simplefilter("ignore")
        fovjax.load_scene(path)


def test_corrupt_glb(tmp_path):
    path = tmp_path / "broken.glb"
    path.write_bytes(b"glTF\x02\x00\x00\x00garbage that is not a glb")
    with pytest.raises(ValueError, match=r"broken\.glb: could not parse glTF binary"):
        fovjax.load_scene(path)


def test_gltf_with_only_points(tmp_path):
    path = tmp_path / "points.glb"
    trimesh.Scene([trimesh.PointCloud(np.random.default_rng(1).random((4, 3)))]).export(path)
    with pytest.raises(ValueError, match=r"points\.glb: the file contains no triangles"):
        fovjax.load_scene(path)
