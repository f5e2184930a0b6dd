"""benchmarks/patney_window.py, the chart of Patney 2016's contrast window against its cost:
a bad command line is refused by name before anything renders."""

import pytest
from _scripts import BENCHMARKS, load_script


def _script():
    return load_script(BENCHMARKS / "patney_window.py")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--windows", "1", "0"], "--windows must be positive, got [1.0, 0.0]"),
        (["--windows", "nan"], "--windows must be positive"),
        (["--frames", "1"], "--frames must be at least 2"),
        (["--warm-up", "-1"], "--warm-up at least 0"),
        (["--size", "4", "4"], "--size at least 8 x 8"),
        (["--scene", "sponza"], "--scene 'sponza': one of ['atrium', 'cornell_box', 'spheres']"),
    ],
)
def test_a_bad_command_line_is_refused_by_name(argv, named, capsys):
    with pytest.raises(SystemExit) as exc:
        _script().main(argv)
    assert exc.value.code == 2 and named in capsys.readouterr().err


def test_contrast_kept_is_one_for_the_reference_and_falls_with_a_blur():
    """The periphery's contrast over the full render's: 1 for the full render itself, below 1
    for a blurred copy (where the blur removed detail), above 1 for added noise."""
    import numpy as np
    from scipy import ndimage

    script = _script()
    rng = np.random.default_rng(0)
    reference = rng.uniform(0.0, 1.0, (32, 48, 3))
    where = np.zeros((32, 48), bool)
    where[:, 24:] = True
    assert script.contrast_kept(reference, reference, where) == pytest.approx(1.0)
    blurred = ndimage.gaussian_filter(reference, (2.0, 2.0, 0.0), mode="nearest")
    assert script.contrast_kept(blurred, reference, where) < 0.5
    noisy = reference + rng.normal(0.0, 0.3, reference.shape)
    assert script.contrast_kept(noisy, reference, where) > 1.1
    # Only the pixels `where` count: blurring pixels beyond their window (3σ) changes nothing.
    half = reference.copy()
    half[:, :8] = blurred[:, :8]
    assert script.contrast_kept(half, reference, where) == 1.0
