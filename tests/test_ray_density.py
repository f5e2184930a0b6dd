"""benchmarks/ray_density.py: full frames at falling resolution on fovjax and Mitsuba 3, cost per
ray against the densest, beside the foveated frame's. A bad size is refused before any work;
a tiny run's figures are consistent (the densest row is the reference, the foveated frame
traces fewer rays than its full frame, the images agree). Mitsuba is in the `[bench]` extra;
without a libLLVM >= 16 for Dr.Jit it skips with the script's own reason."""

import _extras
import pytest
from _scripts import BENCHMARKS, load_script


def _script():
    return load_script(BENCHMARKS / "ray_density.py")


def test_a_bad_size_is_named_before_any_work(capsys):
    bench = _script()
    with pytest.raises(SystemExit) as exc:
        bench.main(["--sizes", "640x512", "640by512"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "640by512" in err and "WIDTHxHEIGHT" in err
    with pytest.raises(SystemExit) as exc:
        bench.main(["--spp", "3"])
    assert exc.value.code == 2 and "--spp 3" in capsys.readouterr().err


def test_tiny_run_figures():
    _extras.require("mitsuba")
    bench = _script()
    try:
        bench.mf.load_mitsuba()
    except bench.mf.Unavailable as exc:
        pytest.skip(str(exc))
    figures = bench.main(["--sizes", "32x24", "16x12", "--max-depth", "2", "--repeats", "1"])
    dense, sparse = figures["rows"]
    assert dense["size"] == "32x24" and sparse["size"] == "16x12"
    assert dense["pixel_density"] == 1.0 and sparse["pixel_density"] == 0.25
    for key in ("mitsuba_full", "fovjax_full"):
        assert dense[f"{key}_cost_per_ray_over_dense"] == 1.0
        assert sparse[f"{key}_ns_per_ray"] > 0
    assert sparse["fovjax_full_rays"] < dense["fovjax_full_rays"]
    assert min(dense["psnr_db"], sparse["psnr_db"]) >= bench.mf.PSNR_EXPECTED
    fov = figures["foveated"]
    assert 0 < fov["rays"] < dense["fovjax_full_rays"] and fov["ns_per_ray"] > 0
    (table,) = figures["tables"]
    assert len(table["rows"]) == 2 and len(table["columns"]) == len(table["rows"][0])
