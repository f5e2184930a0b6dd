"""`load_scene` of a scene made of many files (the thesis loads Sponza from 382 OBJ parts, leaving
out parts 2 and 4, scaled by 2): which files, in which order, skip, scale, the materials of each
file, and every bad-input case, in Python and on `fovjax render`'s command line."""

import warnings

import numpy as np
import pytest
from PIL import Image

import fovjax
import fovjax.trace
from fovjax.cli import main
from fovjax.scene import scene_files

# 12 parts, as Sponza's are numbered: part_0.obj ... part_11.obj. Part i is one triangle at
# height z = i, so a face's height tells which file it came from.
PARTS = 12


def write_parts(folder, count=PARTS, mtl="newmtl stone\nKd 0.5 0.4 0.3\n"):
    folder.mkdir(exist_ok=True)
    (folder / "parts.mtl").write_text(mtl)
    for i in range(count):
        obj = f"mtllib parts.mtl\nv 0 0 {i}\nv 1 0 {i}\nv 0 1 {i}\nusemtl stone\nf 1 2 3\n"
        (folder / f"part_{i}.obj").write_text(obj)
    return folder


def heights(scene):
    return sorted({round(float(z), 6) for z in np.asarray(scene.triangles())[..., 2].ravel()})


def load_quietly(path, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fovjax.load_scene(path, **kwargs)


def test_a_folder_in_number_order_with_skip_and_scale(tmp_path):
    folder = write_parts(tmp_path / "Sponza")
    files = scene_files(folder)
    # numbers compare as numbers: part_10 after part_9 (by plain name it would come after part_1)
    assert [f.name for f in files] == [f"part_{i}.obj" for i in range(PARTS)]
    scene = load_quietly(folder, skip=[2, 4], scale=2.0)
    kept = [i for i in range(PARTS) if i not in (2, 4)]
    assert scene.num_triangles == len(kept)
    assert heights(scene) == [2.0 * i for i in kept]  # part 10 kept, parts 2 and 4 gone, all x2
    assert scene.name == "Sponza"  # the folder's name
    # one MTL shared by every part: one material, not twelve
    assert scene.materials.names == ("stone",)
    np.testing.assert_allclose(np.asarray(scene.materials.kd), [[0.5, 0.4, 0.3]])


def test_a_pattern_and_a_list_read_the_same_files(tmp_path):
    folder = write_parts(tmp_path / "Sponza")
    Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(folder / "part_99.png")  # matched, not a scene
    pattern = str(folder / "part_*")
    assert scene_files(pattern) == scene_files(folder)  # the .mtl and .png matches are left out
    a = load_quietly(pattern, skip=(2, 4))
    b = load_quietly([folder / f"part_{i}.obj" for i in range(PARTS) if i not in (2, 4)])
    np.testing.assert_array_equal(np.asarray(a.vertices), np.asarray(b.vertices))
    np.testing.assert_array_equal(np.asarray(a.faces), np.asarray(b.faces))
    # a list keeps its own order, and each item may itself be a folder or a pattern
    files = scene_files([folder / "part_3.obj", str(folder / "part_1?.obj"), folder / "part_0.obj"])
    assert [f.name for f in files] == ["part_3.obj", "part_10.obj", "part_11.obj", "part_0.obj"]
    assert heights(load_quietly(files, skip=0)) == [0.0, 10.0, 11.0]  # a single index is fine too


def test_each_file_keeps_its_materials(tmp_path):
    # Two files each with their own MTL: "brick" is the same in both (shared), "stone" is not
    # (kept apart, under the second file's name); a texture both use is decoded once.
    Image.fromarray(np.full((2, 2, 3), 200, np.uint8)).save(tmp_path / "wall.png")
    (tmp_path / "a.mtl").write_text("newmtl stone\nKd 1 0 0\nnewmtl brick\nKd 0 1 0\nmap_Kd wall.png\n")
    (tmp_path / "b.mtl").write_text("newmtl stone\nKd 0 0 1\nnewmtl brick\nKd 0 1 0\nmap_Kd wall.png\n")
    for name, z in (("a", 0), ("b", 1)):
        obj = f"mtllib {name}.mtl\nv 0 0 {z}\nv 1 0 {z}\nv 0 1 {z}\nvt 0 0\n"
        obj += "usemtl stone\nf 1/1 2/1 3/1\nusemtl brick\nf 1/1 3/1 2/1\n"
        (tmp_path / f"{name}.obj").write_text(obj)
    scene = load_quietly([tmp_path / "a.obj", tmp_path / "b.obj"])
    m = scene.materials
    assert m.names == ("stone", "brick", "stone (b.obj)")
    np.testing.assert_allclose(np.asarray(m.kd), [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert np.asarray(m.texture).tolist() == [-1, 0, -1] and len(scene.textures) == 1
    z = np.asarray(scene.triangles())[:, 0, 2]
    kd = np.asarray(m.kd)[np.asarray(scene.face_material)]
    # each face has its own file's colour: stone red at z = 0, stone blue at z = 1, brick green in both
    assert sorted((float(zi), tuple(k.tolist())) for zi, k in zip(z, kd, strict=True)) == [
        (0.0, (0.0, 1.0, 0.0)),
        (0.0, (1.0, 0.0, 0.0)),
        (1.0, (0.0, 0.0, 1.0)),
        (1.0, (0.0, 1.0, 0.0)),
    ]


def test_formats_mix_in_a_list(tmp_path):
    write_parts(tmp_path, count=1)
    (tmp_path / "floor.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 5\n1 0 5\n0 1 5\n3 0 1 2\n"
    )
    scene = load_quietly([tmp_path / "part_0.obj", tmp_path / "floor.ply"])
    assert heights(scene) == [0.0, 5.0]
    assert scene.materials.names == ("stone", "default")


# --- bad input -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "skip, message",
    [
        ([2, 12], r"skip index 12 is out of range: the scene has 12 files \(indices 0 to 11\)"),
        ([-1], r"skip index -1 is out of range: the scene has 12 files"),
        (list(range(PARTS)), r"leaves none of the 12 files"),
    ],
)
def test_bad_skip(tmp_path, skip, message):
    with pytest.raises(ValueError, match=message):
        fovjax.load_scene(write_parts(tmp_path / "parts"), skip=skip)


@pytest.mark.parametrize("scale", [0.0, -2.0, float("nan"), float("inf")])
def test_bad_scale(tmp_path, scale):
    with pytest.raises(ValueError, match=rf"scale must be a positive finite number, got {scale!r}"):
        fovjax.load_scene(write_parts(tmp_path / "parts"), scale=scale)


@pytest.mark.parametrize(
    "option, value", [("skip", [1.0]), ("skip", [True]), ("skip", "2"), ("skip", None), ("scale", "2")]
)
def test_skip_and_scale_of_the_wrong_type(tmp_path, option, value):
    # A TypeError naming the argument (from the annotation's check where the tests run with one)
    with pytest.raises(TypeError, match=option):
        fovjax.load_scene(write_parts(tmp_path / "parts"), **{option: value})


def test_a_missing_file_is_reported_before_any_file_is_parsed(tmp_path):
    (tmp_path / "broken.obj").write_text("v 0 0 0\nf 1 2 3\n")  # would fail to parse
    with pytest.raises(FileNotFoundError, match=r"gone\.obj: scene file does not exist"):
        fovjax.load_scene([tmp_path / "broken.obj", tmp_path / "gone.obj"])
    with pytest.raises(ValueError, match=r"notes\.txt: unknown scene format '\.txt'"):
        fovjax.load_scene([tmp_path / "broken.obj", tmp_path / "notes.txt"])


def test_a_bad_file_among_many_names_its_line_and_its_index(tmp_path):
    folder = write_parts(tmp_path / "parts", count=5)
    (folder / "part_3.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    message = r"part_3\.obj:4: v index 9 out of range.*\(index 3 of the 5 scene files; skip=\[3\] leaves"
    with pytest.raises(ValueError, match=message):
        fovjax.load_scene(folder)
    assert load_quietly(folder, skip=[3]).num_triangles == 4  # and leaving it out works


@pytest.mark.parametrize(
    "make, error, message",
    [
        (lambda d: str(d / "*.gltf"), FileNotFoundError, r"\*\.gltf: the pattern matches no scene file"),
        (lambda d: str(d / "*.mtl"), FileNotFoundError, r"matches no scene file .* \(1 other match\)"),
        (lambda d: d / "empty", FileNotFoundError, r"empty: the folder holds no scene file"),
        (lambda d: d, ValueError, r"scene files of 2 formats \(12 \.obj, 1 \.ply\)"),
        (lambda d: [], ValueError, r"an empty list of scene files"),
        (lambda d: [d / "part_0.obj", 3], TypeError, r"item 1 of the list of scene files is 3 \(int\)"),
        (lambda d: 42, TypeError, r"got 42 \(int\)"),
    ],
)
def test_bad_paths(tmp_path, make, error, message):
    write_parts(tmp_path)
    (tmp_path / "empty").mkdir()
    (tmp_path / "also.ply").write_text("ply\n")  # the same folder in two formats
    with pytest.raises(error, match=message):
        fovjax.load_scene(make(tmp_path))


# --- fovjax render --------------------------------------------------------------------------------


class ExpensiveWork(BaseException):
    """Raised instead of building a BVH: a refused input must be refused before that."""


def _trap(*args, **kwargs):
    raise ExpensiveWork("the command started expensive work before refusing its input")


@pytest.mark.parametrize(
    "extra, message",
    [
        (
            ["--scene-skip", "12"],
            "--scene-skip 12: out of range, --scene {folder} has 12 files (indices 0 to 11)",
        ),
        (["--scene-skip", "2,x"], "--scene-skip takes file indices from 0"),
        (["--scene-skip", "-1"], "--scene-skip takes file indices from 0"),
        (["--scene-skip", ",".join(map(str, range(PARTS)))], "--scene-skip leaves none of the 12 files"),
        (["--scene-scale", "0"], "--scene-scale 0"),
        (["--scene-scale", "nan"], "--scene-scale nan"),
    ],
)
def test_render_refuses_bad_skip_and_scale(tmp_path, monkeypatch, capsys, extra, message):
    monkeypatch.setattr(fovjax.trace, "build_bvh", _trap)
    folder = write_parts(tmp_path / "parts")
    try:
        status = main(["render", "--scene", str(folder), *extra, "-o", str(tmp_path / "x.png")])
    except SystemExit as exit_:  # argparse's own errors
        status = exit_.code
    assert status == 2
    err = capsys.readouterr().err
    assert message.format(folder=folder) in err and "Traceback" not in err


def test_render_refuses_skip_for_a_built_in_scene_and_a_pattern_with_no_file(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(fovjax.trace, "build_bvh", _trap)
    out = ["-o", str(tmp_path / "x.png")]
    assert main(["render", "--scene", "cornell", "--scene-skip", "1", *out]) == 2
    assert "apply to scene files, not the built-in cornell" in capsys.readouterr().err
    assert main(["render", "--scene", str(tmp_path / "nothing_*.obj"), *out]) == 2
    assert "the pattern matches no scene file" in capsys.readouterr().err


def test_render_a_folder_with_skip_and_scale(tmp_path, capsys):
    # The geometry preview (primary rays only) of the parts, 8 x 8, written under the folder's name.
    folder = write_parts(tmp_path / "Sponza")
    args = ["render", "--scene", str(folder), "--scene-skip", "2,4", "--scene-scale", "2", "--preview"]
    args += ["--mono", "--width", "8", "--height", "8", "-o", str(tmp_path / "Sponza_preview.png")]
    assert main(args) == 0
    assert f"scene Sponza: {PARTS - 2} triangles" in capsys.readouterr().out
    assert (tmp_path / "Sponza_preview.png").is_file()
