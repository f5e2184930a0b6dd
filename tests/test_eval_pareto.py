"""Pareto selection, the cheapest configuration within a threshold, CSV tables and the charts,
on hand-made tables."""

import math

import imageio.v3 as iio
import numpy as np
import pytest

import fovjax.eval as fe

# Rays per frame (cost) against mean FLIP (error, lower is better) with 95% intervals.
# The front by hand: A (cheapest), B, D, G (least error). C is dominated by B (dearer and
# worse), E by D (same cost, worse), F by D (dearer, same error), H has no error value.
TABLE = [
    {
        "config": "A",
        "rays_per_frame": 100,
        "ms_per_frame": 5.0,
        "flip": 0.30,
        "flip_lo": 0.28,
        "flip_hi": 0.32,
    },
    {
        "config": "B",
        "rays_per_frame": 200,
        "ms_per_frame": 7.0,
        "flip": 0.20,
        "flip_lo": 0.17,
        "flip_hi": 0.23,
    },
    {
        "config": "C",
        "rays_per_frame": 250,
        "ms_per_frame": 9.0,
        "flip": 0.25,
        "flip_lo": 0.20,
        "flip_hi": 0.30,
    },
    {
        "config": "D",
        "rays_per_frame": 300,
        "ms_per_frame": 8.0,
        "flip": 0.10,
        "flip_lo": 0.04,
        "flip_hi": 0.16,
    },
    {
        "config": "E",
        "rays_per_frame": 300,
        "ms_per_frame": 8.5,
        "flip": 0.12,
        "flip_lo": 0.11,
        "flip_hi": 0.13,
    },
    {
        "config": "F",
        "rays_per_frame": 400,
        "ms_per_frame": 11.0,
        "flip": 0.10,
        "flip_lo": 0.09,
        "flip_hi": 0.11,
    },
    {
        "config": "G",
        "rays_per_frame": 500,
        "ms_per_frame": 12.0,
        "flip": 0.05,
        "flip_lo": 0.04,
        "flip_hi": 0.07,
    },
    {
        "config": "H",
        "rays_per_frame": 50,
        "ms_per_frame": 4.0,
        "flip": None,
        "flip_lo": None,
        "flip_hi": None,
    },
]


def names(table, mask):
    return [r["config"] for r, m in zip(table, mask, strict=True) if m]


def test_pareto_front_by_hand():
    front = fe.pareto_front(TABLE, {"rays_per_frame": "min", "flip": "min"})
    assert front.dtype == bool
    assert names(TABLE, front) == ["A", "B", "D", "G"]


def test_pareto_front_senses_and_ties():
    table = [
        {"config": "a", "ms": 1.0, "ssim": 0.90},
        {"config": "b", "ms": 2.0, "ssim": 0.95},
        {"config": "c", "ms": 2.0, "ssim": 0.95},  # equal to b: neither dominates the other
        {"config": "d", "ms": 3.0, "ssim": 0.94},  # dearer and worse than b
        {"config": "e", "ms": 4.0, "ssim": 0.99},
        {"config": "f", "ms": math.nan, "ssim": 1.0},  # no cost: off the front, dominates nothing
    ]
    assert names(table, fe.pareto_front(table, {"ms": "min", "ssim": "max"})) == ["a", "b", "c", "e"]
    # Flipping a sense flips the problem: minimal ssim as well -> only the cheapest and worst.
    assert names(table, fe.pareto_front(table, {"ms": "min", "ssim": "min"})) == ["a"]
    # One objective: the minima only.
    assert names(table, fe.pareto_front(table, {"ms": "min"})) == ["a"]
    # Three objectives: ms_per_frame makes D (8 ms) and E (8.5) both cheaper in time than F.
    three = fe.pareto_front(TABLE, {"rays_per_frame": "min", "ms_per_frame": "min", "flip": "min"})
    assert names(TABLE, three) == ["A", "B", "D", "G"]


def test_pareto_front_structured_array_and_errors():
    arr = np.array(
        [(100, 0.3), (200, 0.2), (250, 0.25), (300, 0.1)], dtype=[("rays_per_frame", "i8"), ("flip", "f8")]
    )
    assert fe.pareto_front(arr, {"rays_per_frame": "min", "flip": "min"}).tolist() == [
        True,
        True,
        False,
        True,
    ]
    assert fe.as_records(arr)[1] == {"rays_per_frame": 200, "flip": 0.2}
    assert fe.pareto_front([], {"x": "min"}).shape == (0,)
    with pytest.raises(ValueError, match="'min' or 'max'"):
        fe.pareto_front(TABLE, {"flip": "lowest"})
    with pytest.raises(ValueError, match="record 0 has no column 'psnr'"):
        fe.pareto_front(TABLE, {"psnr": "max"})
    with pytest.raises(ValueError, match="record 1, column 'x'"):
        fe.pareto_front([{"x": 1}, {"x": "fast"}], {"x": "min"})
    with pytest.raises(ValueError, match="structured array"):
        fe.as_records(np.zeros(3))


def test_cheapest_within_threshold():
    # FLIP below 0.15 with the whole interval: D's interval reaches 0.16, E's 0.13 -> E (300 rays;
    # F is dearer, G dearer still).
    choice = fe.cheapest_within(TABLE, cost="rays_per_frame", metric="flip", threshold=0.15)
    assert choice.name == "E" and choice.index == 4
    assert "flip_hi = 0.13 < 0.15" in choice.criterion and "rays_per_frame = 300" in choice.criterion
    # On the point value, D and E tie on cost: the lower error (D) wins.
    by_value = fe.cheapest_within(
        TABLE, cost="rays_per_frame", metric="flip", threshold=0.15, use_interval=False
    )
    assert by_value.name == "D"
    # Another cost column gives another answer: D is the fastest qualifying in ms.
    assert (
        fe.cheapest_within(TABLE, cost="ms_per_frame", metric="flip", threshold=0.15, use_interval=False).name
        == "D"
    )
    # Nothing qualifies.
    assert fe.cheapest_within(TABLE, cost="rays_per_frame", metric="flip", threshold=0.01) is None
    # Strictly below: a bound equal to the threshold does not qualify.
    assert fe.cheapest_within(TABLE, cost="rays_per_frame", metric="flip", threshold=0.07) is None
    assert fe.cheapest_within(TABLE, cost="rays_per_frame", metric="flip", threshold=0.0701).name == "G"
    assert str(choice).startswith("E (lowest rays_per_frame")


def test_cheapest_within_higher_is_better():
    table = [
        {"config": "cheap", "rays": 10, "jod": 8.0, "jod_lo": 7.5, "jod_hi": 8.5},
        {"config": "mid", "rays": 20, "jod": 9.3, "jod_lo": 8.8, "jod_hi": 9.8},
        {"config": "dear", "rays": 40, "jod": 9.8, "jod_lo": 9.6, "jod_hi": 9.9},
    ]
    # JOD above 9 with the lower bound of the interval: "mid" dips to 8.8, so "dear".
    assert fe.cheapest_within(table, cost="rays", metric="jod", threshold=9.0, below=False).name == "dear"
    assert (
        fe.cheapest_within(
            table, cost="rays", metric="jod", threshold=9.0, below=False, use_interval=False
        ).name
        == "mid"
    )
    unnamed = [{k: v for k, v in r.items() if k != "config"} for r in table]
    assert (
        fe.cheapest_within(unnamed, cost="rays", metric="jod", threshold=9.0, below=False).name == "record 2"
    )


def test_csv_round_trip(tmp_path):
    table = TABLE + [{"config": "I", "rays_per_frame": 1, "flip": math.inf, "on_front": True, "note": "x, y"}]
    path = fe.write_csv(table, tmp_path / "sub" / "table.csv")
    back = fe.read_csv(path)
    assert len(back) == len(table)
    header = path.read_text().splitlines()[0].split(",")
    assert header == [
        "config",
        "rays_per_frame",
        "ms_per_frame",
        "flip",
        "flip_lo",
        "flip_hi",
        "on_front",
        "note",
    ]
    for orig, row in zip(table, back, strict=True):
        for key in header:
            assert row[key] == orig.get(key), key
    assert isinstance(back[0]["rays_per_frame"], int) and isinstance(back[0]["flip"], float)
    assert back[-1]["on_front"] is True and back[-1]["note"] == "x, y"
    # Full float precision.
    fe.write_csv([{"v": 0.1 + 0.2}], tmp_path / "p.csv")
    assert fe.read_csv(tmp_path / "p.csv")[0]["v"] == 0.1 + 0.2
    # Chosen columns.
    fe.write_csv(TABLE, tmp_path / "few.csv", columns=["config", "flip"])
    assert fe.read_csv(tmp_path / "few.csv")[0] == {"config": "A", "flip": 0.3}


def test_mean_interval():
    # [1, 2, 3]: mean 2, sd 1, t(0.975, 2) = 4.302652729749462 -> half-width 4.3027 / sqrt(3).
    m, lo, hi = fe.mean_interval([1.0, 2.0, 3.0])
    half = 4.302652729749462 / math.sqrt(3)
    assert (m, lo, hi) == pytest.approx((2.0, 2.0 - half, 2.0 + half))
    assert fe.mean_interval([5.0])[0] == 5.0 and math.isnan(fe.mean_interval([5.0])[1])
    m, lo, hi = fe.mean_interval([30.0, math.inf])  # PSNR of an identical frame
    assert m == math.inf and math.isnan(lo) and math.isnan(hi)
    with pytest.raises(ValueError, match="NaN"):
        fe.mean_interval([1.0, math.nan])
    with pytest.raises(ValueError, match="no samples"):
        fe.mean_interval([])


# --- charts -------------------------------------------------------------------------------------


def assert_png(path, min_size=(300, 300)):
    image = iio.imread(path)
    assert image.shape[0] >= min_size[1] and image.shape[1] >= min_size[0]
    assert image[..., :3].std() > 5  # something drawn


def test_plot_cost_accuracy(tmp_path):
    path = fe.plot_cost_accuracy(
        TABLE, tmp_path / "cost.png", cost="rays_per_frame", accuracy="flip", sense="min", threshold=0.15
    )
    assert_png(path)
    arr = np.array([(1.0, 0.9), (2.0, 0.95)], dtype=[("ms", "f8"), ("ssim", "f8")])
    assert_png(
        fe.plot_cost_accuracy(arr, tmp_path / "s.png", cost="ms", accuracy="ssim", sense="max", log_cost=True)
    )
    with pytest.raises(ValueError, match="empty"):
        fe.plot_cost_accuracy([], tmp_path / "e.png", cost="x", accuracy="y", sense="min")


def test_plot_metric_bars(tmp_path):
    table = [r | {"psnr": 30.0 + i} for i, r in enumerate(TABLE)]
    table[0]["psnr"] = math.inf
    assert_png(fe.plot_metric_bars(table, tmp_path / "bars.png", metrics=["flip", "psnr"]))
    with pytest.raises(ValueError, match="no column"):
        fe.plot_metric_bars(TABLE, tmp_path / "x.png", metrics=["ssim"])


def test_plot_ring_errors(tmp_path):
    ecc = np.tile(np.arange(30, dtype=float), (11, 1))
    ref = np.full((11, 30, 3), 0.4)
    rings = {}
    for name, start in (("5/10", 5), ("10/20", 10)):
        test = ref.copy()
        test[:, start:] += 0.05
        rings[name] = fe.error_by_eccentricity(test, ref, ecc)
    rays = {name: [1000, 500, 120, 60, 60, 60] for name in rings}
    assert_png(fe.plot_ring_errors(rings, tmp_path / "rings.png", rays=rays))
    assert_png(fe.plot_ring_errors(rings, tmp_path / "rings_only.png"))
    with pytest.raises(ValueError, match="2 ray counts for 6 rings"):
        fe.plot_ring_errors(rings, tmp_path / "bad.png", rays={"5/10": [1, 2]})
