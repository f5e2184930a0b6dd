"""Acuity data: the shipped files, the schema, bad data, the MAR conversion."""

import csv
from pathlib import Path

import jax
import numpy as np
import pytest

import fovjax.acuity as fa

REPO = Path(__file__).resolve().parents[1]
CURVE = REPO / "data" / "mandelbaum" / "curve_samples.csv"
PUBLISHED = REPO / "data" / "published"
HEADER = "eccentricity_deg,acuity,sd,n,condition,source\n"


def write(tmp_path, text, name="d.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_curve_samples_are_labelled_and_lie_on_the_thesis_curve():
    head = CURVE.read_text().splitlines()[0]
    assert "POINTS ON A PUBLISHED FIT, NOT MEASUREMENTS" in head
    data = fa.load_csv(CURVE)
    assert len(data) >= 10 and not data.weighted
    assert all("not a measurement" in s for s in data.source)
    with jax.enable_x64(True):
        expected = np.asarray(fa.THESIS_MODEL(data.eccentricity_deg))
    # Written to 10 significant digits.
    np.testing.assert_allclose(data.acuity, expected, rtol=1e-9)
    assert data.sha256 is not None and len(data.sha256) == 64


def test_published_linear_mar_points_follow_from_the_figures_table():
    figures = [
        r
        for r in csv.DictReader(line for line in open(PUBLISHED / "figures.csv") if not line.startswith("#"))
    ]
    by = {(r["citation"].split(",")[0], r["quantity"]): float(r["value"]) for r in figures}
    for r in figures:
        assert r["kind"] in {"measurement", "published_fit", "quoted_value", "formula"}, r
    eye = "Central-field perimetry of discriminated targets"
    expected_e2 = sorted(
        [
            by[("Jones & Higgins 1947", "half_acuity_eccentricity")],
            by[("Ludvigh 1941", "half_acuity_eccentricity")],
            by[("Song", "nominal_acuity_e2")],
            by[("Rovamo & Virsu 1979 (tabulated by Strasburger et al. 2011)", "e2")],
            by[(eye, "mar_intercept")] / by[(eye, "mar_slope")],  # MAR0/slope = E2
        ]
    )
    data = fa.load_csv(PUBLISHED / "linear_mar_e2.csv")
    np.testing.assert_allclose(np.sort(data.eccentricity_deg), expected_e2, rtol=1e-9)
    np.testing.assert_array_equal(data.acuity, 0.5)  # relative acuity 1/(1 + E2/E2)


def test_round_trip_save_and_load(tmp_path):
    data = fa.from_arrays([0.0, 2.0, 5.0], [1.0, 0.6, 0.3], sd=[0.1, 0.05, 0.04], n=[3, 4, 5], condition="x")
    fa.save_csv(data, tmp_path / "r.csv", comment="a comment\nsecond line")
    back = fa.load_csv(tmp_path / "r.csv")
    np.testing.assert_allclose(back.acuity, data.acuity)
    np.testing.assert_allclose(back.se, data.sd / np.sqrt([3, 4, 5]))
    assert back.conditions == ("x",)


def test_mar_conversion(tmp_path):
    acuity, sd = fa.mar_to_acuity(np.array([1.0, 2.0, 4.0]), np.array([0.1, 0.2, 0.4]))
    np.testing.assert_allclose(acuity, [1.0, 0.5, 0.25])  # decimal acuity = 1'/MAR
    np.testing.assert_allclose(sd, [0.1, 0.05, 0.025])  # delta method: sd/MAR²
    path = write(
        tmp_path,
        "eccentricity_deg,mar_arcmin,sd,n,condition,source\n0,1.75,,,p,s\n10,5.81,,,p,s\n5,3.4,,,p,s\n",
    )
    rel = fa.load_csv(path, mar_reference_arcmin="fovea")
    np.testing.assert_allclose(rel.acuity, [1.0, 1.75 / 5.81, 1.75 / 3.4])
    dec = fa.load_csv(path)
    np.testing.assert_allclose(dec.acuity, [1 / 1.75, 1 / 5.81, 1 / 3.4])
    no_fovea = write(
        tmp_path, "eccentricity_deg,mar_arcmin,sd,n,condition,source\n2,2,,,p,s\n4,3,,,p,s\n", "m.csv"
    )
    with pytest.raises(fa.AcuityDataError, match="no row at eccentricity 0"):
        fa.load_csv(no_fovea, mar_reference_arcmin="fovea")


BAD = {
    "nan": (HEADER + "0,1.0,,,c,s\n2,nan,,,c,s\n", r"d\.csv:3: acuity is nan, not a finite number"),
    "negative": (HEADER + "0,1.0,,,c,s\n2,-0.3,,,c,s\n", r"d\.csv:3: acuity = -0.3 must be > 0"),
    "zero": (HEADER + "0,1.0,,,c,s\n2,0,,,c,s\n", r"d\.csv:3: acuity = 0 must be > 0"),
    "duplicate": (
        HEADER + "0,1.0,,,c,s\n2,0.5,,,c,s\n2,0.4,,,c,s\n",
        r"d\.csv:4: duplicate eccentricity_deg = 2 in condition 'c' \(also at .*d\.csv:3\)",
    ),
    "single": (HEADER + "0,1.0,,,c,s\n", r"a single data row \(eccentricity 0\) cannot define a curve"),
    "empty": ("", r"d\.csv: empty file"),
    "comments only": ("# nothing here\n\n", r"d\.csv: empty file"),
    "header only": (HEADER, r"header only, no data rows"),
    "wrong column": (
        "eccentricity,acuity,sd,n,condition,source\n0,1,,,c,s\n",
        r"d\.csv:1: missing column\(s\) \['eccentricity_deg'\]; unknown column\(s\) \['eccentricity'\]",
    ),
    "extra column": (
        "eccentricity_deg,acuity,sd,n,condition,source,notes\n0,1,,,c,s,x\n",
        r"unknown column\(s\) \['notes'\]",
    ),
    "not a number": (
        HEADER + "0,1.0,,,c,s\nfive,0.5,,,c,s\n",
        r"d\.csv:3: eccentricity_deg = 'five' is not a number",
    ),
    "negative eccentricity": (
        HEADER + "0,1.0,,,c,s\n-2,0.5,,,c,s\n",
        r"d\.csv:3: eccentricity_deg = -2 is negative",
    ),
    "partial sd": (
        HEADER + "0,1.0,0.1,,c,s\n2,0.5,,,c,s\n",
        r"sd is given on line\(s\) \[2\] but blank on line\(s\) \[3\]",
    ),
    "zero sd": (HEADER + "0,1.0,0.1,,c,s\n2,0.5,0,,c,s\n", r"d\.csv:3: sd = 0 must be a finite number > 0"),
    "fractional n": (
        HEADER + "0,1.0,,2.5,c,s\n2,0.5,,,c,s\n",
        r"d\.csv:2: n = 2.5 must be a whole number >= 1",
    ),
    "short row": (HEADER + "0,1.0,,,c\n2,0.5,,,c,s\n", r"d\.csv:2: 5 fields, header has 6"),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_bad_data_is_rejected_with_the_place_and_the_problem(tmp_path, case):
    text, message = BAD[case]
    with pytest.raises(fa.AcuityDataError, match=message):
        fa.load_csv(write(tmp_path, text))


def test_missing_file():
    with pytest.raises(fa.AcuityDataError, match="cannot read"):
        fa.load_csv("/nonexistent/acuity.csv")


def test_array_input_errors_name_the_row():
    with pytest.raises(fa.AcuityDataError, match=r"arrays row 1: acuity is nan"):
        fa.from_arrays([0.0, 1.0], [1.0, np.nan])
    with pytest.raises(fa.AcuityDataError, match="no data rows"):
        fa.from_arrays([], [])
    with pytest.raises(fa.AcuityDataError, match=r"sd has 1 entries for 2 rows"):
        fa.from_arrays([0.0, 1.0], [1.0, 0.5], sd=[0.1])


def test_conditions_are_fitted_one_at_a_time(tmp_path):
    path = write(
        tmp_path,
        HEADER
        + "".join(
            f"{w},{v},,,{c},s\n" for c in ("A", "B") for w, v in ((0, 1), (2, 0.5), (5, 0.3), (9, 0.2))
        ),
    )
    data = fa.load_csv(path)  # the same eccentricity in two conditions is fine
    assert data.conditions == ("A", "B")
    with pytest.raises(fa.AcuityDataError, match=r"2 conditions \['A', 'B'\]; fit one at a time"):
        fa.fit(data, "linear_mar")
    assert fa.fit(data, "linear_mar", condition="B").data.conditions == ("B",)
    with pytest.raises(fa.AcuityDataError, match="no rows with condition 'C'"):
        data.select("C")
