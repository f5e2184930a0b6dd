"""CONTRIBUTING.md's "Add a foveation method" runs as written: its Python block (a method that
traces the fovea and paints every other pixel one colour, registered, then a frame rendered with
it) is executed here, and the frame is checked against what the method says it does: exactly the
fovea's pixels are traced (the sample mask and the primary-ray count, against the frame's own
eccentricity map), every other pixel is the fill colour bit for bit (a copied constant), and the
fovea's pixels are the full render's (another program: float32 rounding, tests/_frames.py).
Beside it: the registry's checks of a method class, and the command line's use of the registry.
The example's tiny rig (the Cornell box at 2 x 32x24, depth 0) is tests/test_eval_compare.py's,
so the full render's program is shared."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest
from _frames import assert_same_radiance

from fovjax.foveate import METHODS, AbstractFoveationMethod, Foveation, method_label, register_method
from fovjax.foveate._methods import _registry

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Add a foveation method"


def example_code() -> str:
    """The Python blocks of CONTRIBUTING.md's section, in order."""
    text = (ROOT / "CONTRIBUTING.md").read_text()
    assert SECTION in text, f"CONTRIBUTING.md has no {SECTION!r} section"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, f"CONTRIBUTING.md's {SECTION!r} has no python block"
    return "\n".join(blocks)


@pytest.fixture(scope="module")
def example():
    """The namespace the example leaves (its class, renderer and frame); its method is taken out
    of the registry afterwards, so no other test sees it."""
    module = types.ModuleType("contributing_example")  # run as a user's script would be
    sys.modules[module.__name__] = module
    try:
        # dont_inherit: the block is compiled without this file's `from __future__` imports.
        exec(compile(example_code(), "CONTRIBUTING.md", "exec", dont_inherit=True), module.__dict__)
        yield module.__dict__
    finally:
        _registry._REGISTRY.pop("fovea-only", None)
        del sys.modules[module.__name__]


def test_the_example_is_registered_by_name(example):
    cls = example["FoveaOnly"]
    assert METHODS["fovea-only"] is cls and issubclass(cls, AbstractFoveationMethod)
    assert Foveation(method="fovea-only").method == cls()
    assert method_label(cls(fill=(1.0, 0.0, 0.0))) == "fovea-only(fill=(1.0, 0.0, 0.0))"
    assert not cls.temporal and not cls.batches and cls().widens_fovea
    with pytest.raises(ValueError, match="ray_budget apply to the thesis's method only"):
        Foveation(method="fovea-only", ray_budget=100)
    with pytest.raises(ValueError, match="one after another"):
        example["renderer"].render_batch([((0.5, 0.5), (0.5, 0.5))])


def test_the_example_traces_exactly_the_fovea(example):
    frame, renderer, foveation = example["frame"], example["renderer"], example["foveation"]
    spp = foveation.spp
    fovea = frame.eccentricity <= foveation.fovea_deg  # (2, H, W), the frame's own map
    assert 0 < fovea.sum() < fovea.size  # the gaze's fovea, not the whole screen
    assert (frame.sample_mask == fovea[:, None]).all()
    assert frame.stats.primary_rays == spp * int(fovea.sum())
    assert frame.foveation.reused == 0 and frame.history is None
    side_by_side = fovea.transpose(1, 0, 2).reshape(fovea.shape[1], -1)  # eyes side by side
    assert (frame.image[~side_by_side] == 0.0).all()  # the fill, (0, 0, 0)
    full = renderer.render_full().image
    assert_same_radiance(frame.image[side_by_side], full[side_by_side])


def test_the_command_line_takes_the_registered_name(example, tmp_path, capsys):
    """`fovjax compare --methods` checks names against the registry: the example's passes that
    check and the command stops at the next one (an output path that is a file), before any work."""
    from fovjax.cli import main

    a_file = tmp_path / "a_file"
    a_file.write_text("")
    argv = ["compare", "--scene", "cornell_box", "--methods", "thesis", "fovea-only", "-o", str(a_file)]
    assert main(argv) != 0
    assert "exists and is not a folder" in capsys.readouterr().err
    assert main([*argv[:4], "fovea-only-nope", *argv[6:]]) != 0
    assert "--methods 'fovea-only-nope': expected one of thesis" in capsys.readouterr().err


class _Named(AbstractFoveationMethod):
    """A method class for the registry's checks (never registered whole)."""

    name = "registry-check"
    citation = None

    def frame(self, inputs, history, *, options):
        raise AssertionError("not rendered")


@pytest.mark.parametrize(
    ("attributes", "error", "message"),
    [
        ({"name": "Bad Name"}, ValueError, "name 'Bad Name': expected lower-case letters"),
        ({"name": "thesis"}, ValueError, "name 'thesis' is taken by fovjax.foveate._methods._catalog.Thesis"),
        ({"citation": "a paper"}, ValueError, "citation 'a paper': expected a Citation or None"),
        ({"thesis_options": frozenset({"blur"})}, ValueError, "thesis_options ['blur']"),
        ({"temporal": True}, ValueError, "temporal is True but the class does not define empty_history"),
        ({"frame": None}, TypeError, "the class is abstract: define frame"),
    ],
)
def test_register_method_says_what_is_wrong(attributes, error, message):
    body = dict(attributes)
    if body.get("frame", True) is None:  # no frame program: the abstract method stays abstract
        body.pop("frame")
        cls = type("Incomplete", (AbstractFoveationMethod,), {"name": "incomplete", "citation": None})
    else:
        cls = type("Bad", (_Named,), body)
    with pytest.raises(error, match=re.escape(message)):
        register_method(cls)
    assert cls not in METHODS.values()


@pytest.mark.no_typecheck
def test_register_method_refuses_a_class_that_is_not_a_method():
    with pytest.raises(TypeError, match="expected a subclass of AbstractFoveationMethod, got <class 'int'>"):
        register_method(int)  # pyright: ignore[reportArgumentType]


def test_an_unregistered_method_instance_is_refused():
    with pytest.raises(ValueError, match="is not a registered method: register it with"):
        Foveation(method=_Named())
