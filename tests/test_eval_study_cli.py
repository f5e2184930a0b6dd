"""`fovjax study` and the study from a comparison table: hand-made comparison tables (no
rendering) whose metric crosses the just-noticeable threshold between two known levels, the
observers' answers and majorities derived by hand, the CLI's files and printout, the
--responses round trip, and the errors."""

import math
import re

import imageio.v3 as iio
import pytest

import fovjax.eval as fe
from fovjax.cli import main

LEVELS = [(5.0, 10.0), (7.5, 15.0), (10.0, 20.0), (12.5, 25.0), (15.0, 30.0)]

# Two rows per level at spp 4 (e.g. two runs of `fovjax compare` concatenated); the mean
# decides. At 10/20 the first row alone would land on the other side of the threshold.
# JOD: d = 10 - mean JOD = 3.0, 1.8, 1.1, 0.7, 0.4 -> seen (d > 1) up to 10/20.
JOD = {
    (5.0, 10.0): (6.8, 7.2),
    (7.5, 15.0): (8.0, 8.4),
    (10.0, 20.0): (9.5, 8.3),
    (12.5, 25.0): (9.2, 9.4),
    (15.0, 30.0): (9.6, 9.6),
}
# FLIP: d = mean FLIP = 0.2, 0.08, 0.04, 0.03, 0.02 -> seen (d > 0.05) up to 7.5/15.
FLIP = {
    (5.0, 10.0): (0.18, 0.22),
    (7.5, 15.0): (0.07, 0.09),
    (10.0, 20.0): (0.06, 0.02),
    (12.5, 25.0): (0.03, 0.03),
    (15.0, 30.0): (0.02, 0.02),
}


def make_table(metric="jod", values=None, *, spp1=True, models=("thesis",)):
    """Records as `fovjax compare` writes them: per level and model two rows at spp 4 with
    `values`, and (with `spp1`) one row at spp 1 where every level is clearly visible, so that
    reading the wrong spp changes every answer."""
    values = {"jod": JOD, "flip": FLIP}[metric] if values is None else values
    rows = []
    for model in models:
        for (f, p), vals in values.items():
            for v in vals:
                rows.append(_row(f, p, 4, model, metric, v))
            if spp1:
                rows.append(_row(f, p, 1, model, metric, 5.0 if metric == "jod" else 0.5))
    return rows


def _row(f, p, spp, model, metric, v):
    row = {
        "config": f"{f:g}/{p:g} spp{spp}" + ("" if model == "thesis" else f" {model}"),
        "fovea_deg": f,
        "periphery_deg": p,
        "spp": spp,
        "model": model,
        "rays_per_frame": 1000.0 * f,
        "psnr": 30.0,
        "psnr_lo": 29.0,
        "psnr_hi": 31.0,
        "flip": v if metric == "flip" else 0.01,
    }
    if metric == "jod":
        row.update(jod=v, jod_lo=v - 0.1, jod_hi=v + 0.1)
    return row


def write_table(tmp_path, rows, name="compare"):
    return fe.write_csv(rows, tmp_path / name / "comparison.csv")


# (metric, threshold given, lowest level whose difference is not seen) - by hand from the
# tables above; the threshold override moves FLIP's crossing up one level (0.04 > 0.035 > 0.03).
CROSSINGS = [("jod", None, 12.5), ("flip", None, 10.0), ("flip", 0.035, 12.5)]


@pytest.mark.parametrize("metric", ["jod", "flip"])
def test_difference_is_the_mean_over_the_levels_rows_at_the_spp(metric):
    diff = fe.difference_from_comparison(make_table(metric), metric=metric, spp=4)
    values = {"jod": JOD, "flip": FLIP}[metric]
    for level, vals in values.items():
        mean = sum(vals) / 2
        assert diff.means[level] == pytest.approx(mean)
        assert diff.differences[level] == pytest.approx(10 - mean if metric == "jod" else mean)
        assert diff.rows[level] == 2
    assert (diff.metric, diff.spp, diff.model) == (metric, 4, "thesis")
    assert diff.threshold == {"jod": fe.JND_JOD, "flip": 0.05}[metric]
    # The trial's level picks the value.
    assert diff(fe.slider_trial(start=3)) == pytest.approx(diff.differences[(12.5, 25.0)])


@pytest.mark.parametrize(("metric", "threshold", "first_same"), CROSSINGS)
def test_noise_free_observers_answer_same_exactly_below_threshold(metric, threshold, first_same):
    observers = fe.observers_from_comparison(
        make_table(metric), metric=metric, spp=4, observers=fe.ObserverPanel(n=3, threshold=threshold)
    )
    responses = fe.run_study(observers)
    assert len(responses) == 3 * 21
    for r in responses:
        if r.trial.test == "pair":
            hidden = r.trial.fovea_deg >= first_same
            expected = "same" if hidden else ("first" if r.trial.order == "reference_first" else "second")
            assert r.answer == expected, r.trial.condition
        elif r.trial.test == "ramp":
            assert (r.answer == "same") == (r.trial.fovea_deg >= first_same), r.trial.condition
        else:
            assert r.answer == f"{first_same:g}"
    pair = {row["fovea_deg"]: row["proportion_same"] for row in fe.analyse_pair(responses)}
    assert pair == {f: (1.0 if f >= first_same else 0.0) for f, _ in LEVELS}
    slider = {row["fovea_deg"]: row["participants"] for row in fe.analyse_slider(responses)}
    assert slider == {f: (3 if f == first_same else 0) for f, _ in LEVELS}
    assert fe.study_majorities(responses) == dict.fromkeys(
        ("pair", "ramp up", "ramp down", "slider"), first_same
    )


def test_noisy_observers_differ_and_follow_the_seed():
    table = make_table("jod")

    def answers(seed):
        observers = fe.observers_from_comparison(
            table, observers=fe.ObserverPanel(n=8, noise_sd=0.8, seed=seed)
        )
        return [r.answer for r in fe.run_study(observers)]

    seeds = [
        o.seed
        for o in fe.observers_from_comparison(table, observers=fe.ObserverPanel(n=8, noise_sd=0.8, seed=1))
    ]
    assert len(set(seeds)) == 8
    per_observer = [tuple(answers(1)[k * 21 : (k + 1) * 21]) for k in range(8)]
    assert len(set(per_observer)) > 1  # noise makes the observers differ
    assert answers(1) == answers(1)
    assert answers(1) != answers(2)


def test_study_majority_of_the_slider_is_the_median_choice():
    trial = fe.slider_trial()
    chosen = ["5", "12.5", "12.5", "15", "15"]  # 1/5, 3/5 at or below 12.5 -> 12.5
    responses = [fe.Response(f"p{k}", trial, a) for k, a in enumerate(chosen)]
    assert fe.study_majorities(responses) == {"slider": 12.5}


def assert_refused(argv, message, capsys):
    """`fovjax study` ends with status 2 and one error line matching `message`, no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fovjax study: error: ") and re.search(message, err), err
    assert "Traceback" not in err


def majority_lines(text):
    return [
        line.split() for line in text.splitlines() if re.match(r"\s*(pair|ramp up|ramp down|slider)\s", line)
    ]


@pytest.mark.parametrize(("metric", "threshold", "first_same"), CROSSINGS)
@pytest.mark.parametrize("as_dir", [True, False])
def test_cli_writes_answers_figures_and_majorities(tmp_path, capsys, metric, threshold, first_same, as_dir):
    csv_path = write_table(tmp_path, make_table(metric))
    out = tmp_path / "study"
    argv = ["study", "--comparison", str(csv_path.parent if as_dir else csv_path), "-o", str(out)]
    if threshold is not None:
        argv += ["--threshold", str(threshold)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert f"note: metric {metric}" in text  # chosen by default: jod when the table has it

    responses = fe.read_responses(out / "responses.csv")
    assert len(responses) == 15 * 21
    assert len({r.participant for r in responses}) == 15
    for name in ("fig66_pair_test.png", "fig67_ramp_test.png", "fig68_slider_test.png"):
        image = iio.imread(out / name)
        assert image.ndim == 3 and image.shape[0] > 100
    for name in ("pair_test.csv", "ramp_test.csv", "slider_test.csv"):
        assert fe.read_csv(out / name)

    level = dict(LEVELS)[first_same]
    lines = majority_lines(text)
    assert [line[:-2] if line[0] != "ramp" else line[:2] for line in lines] == [
        ["pair"],
        ["ramp", "up"],
        ["ramp", "down"],
        ["slider"],
    ]
    for line in lines:
        assert line[-2:] == [f"{first_same:g}°/{level:g}°", "12.5°/25°"]
    majority = fe.read_csv(out / "majority.csv")
    assert [r["test"] for r in majority] == ["pair", "ramp up", "ramp down", "slider"]
    assert all(r["majority_fovea_deg"] == first_same and r["thesis_fovea_deg"] == 12.5 for r in majority)


def test_cli_metric_choice_spp_and_model(tmp_path, capsys):
    # Two models; at spp 1 every level is seen, so the slider goes to the end (15).
    rows = make_table("jod", models=("thesis", "other"))
    rows = [r if r["model"] == "thesis" else {**r, "jod": 9.9} for r in rows]
    csv_path = write_table(tmp_path, rows)
    base = ["study", "--comparison", str(csv_path), "--observers", "2"]
    assert main([*base, "--model", "thesis", "--metric", "flip", "-o", str(tmp_path / "a")]) == 0
    text = capsys.readouterr().out
    assert "note: metric" not in text  # asked for, not defaulted
    assert all(line[-2] == "5°/10°" for line in majority_lines(text))  # FLIP 0.01 everywhere
    assert main([*base, "--model", "other", "-o", str(tmp_path / "b")]) == 0
    assert all(line[-2] == "5°/10°" for line in majority_lines(capsys.readouterr().out))  # JOD 9.9
    assert main([*base, "--model", "thesis", "--spp", "1", "-o", str(tmp_path / "c")]) == 0
    text = capsys.readouterr().out
    assert "every level is seen" in text  # the slider's 15/30 is then no equivalence
    lines = [" ".join(line) for line in majority_lines(text)]
    assert lines == [
        f"{test} none (no level has a majority) 12.5°/25°" for test in ("pair", "ramp up", "ramp down")
    ] + ["slider 15°/30° 12.5°/25°"]


def test_cli_responses_reproduces_the_report(tmp_path, capsys):
    csv_path = write_table(tmp_path, make_table("jod"))
    first = tmp_path / "first"
    argv = ["study", "--comparison", str(csv_path), "--noise-sd", "0.5", "--seed", "7", "--shuffle"]
    assert main([*argv, "-o", str(first)]) == 0
    printed = majority_lines(capsys.readouterr().out)
    responses = fe.read_responses(first / "responses.csv")
    assert (
        len({r.trial.index for r in responses if r.trial.test == "pair" and r.trial.level == (5.0, 10.0)}) > 1
    )

    # The same file, and the same answers split over two files by participant.
    half = sorted({r.participant for r in responses})[:7]
    a = fe.write_responses([r for r in responses if r.participant in half], tmp_path / "a.csv")
    b = fe.write_responses([r for r in responses if r.participant not in half], tmp_path / "b.jsonl")
    for k, files in enumerate([[first / "responses.csv"], [a, b]]):
        again = tmp_path / f"again{k}"
        assert main(["study", "--responses", *map(str, files), "-o", str(again)]) == 0
        text = capsys.readouterr().out
        assert f"read {15 * 21} answers from 15 participant(s) in {len(files)} file(s)" in text
        assert majority_lines(text) == printed
        for name in ("pair_test.csv", "ramp_test.csv", "slider_test.csv", "majority.csv"):
            assert (again / name).read_text() == (first / name).read_text(), name
        assert (again / "fig66_pair_test.png").is_file() and not (again / "responses.csv").exists()


def test_a_folder_whose_log_ends_in_a_cut_line_is_read_without_it(tmp_path, capsys):
    """A crash inside the write of the last answer leaves a cut line (`fovjax view --study`
    drops it when it resumes): `--responses FOLDER` reads the rest and says which line it left
    out, in one warning line."""
    csv_path = write_table(tmp_path, make_table("jod"))
    assert main(["study", "--comparison", str(csv_path), "--observers", "2", "-o", str(tmp_path / "a")]) == 0
    responses = fe.read_responses(tmp_path / "a" / "responses.csv")
    folder = tmp_path / "answers"
    folder.mkdir()
    log = fe.write_responses(responses, folder / "p01_pair.jsonl")
    lines = log.read_text().count("\n")
    with log.open("a") as fh:
        fh.write('{"participant": "p01", "test": "pa')  # the process died here
    capsys.readouterr()
    assert main(["study", "--responses", str(folder), "-o", str(tmp_path / "b")]) == 0
    out, err = capsys.readouterr()
    assert f"read {len(responses)} answers" in out
    warning = [line for line in err.splitlines() if "warning" in line]
    assert warning == [
        f"fovjax study: warning: {log}:{lines + 1}: the last line is cut off (the writer stopped inside it); "
        "left out"
    ]
    # A line that is not JSON anywhere else is still an error naming it.
    log.write_text(log.read_text() + "\n" + '{"participant": "p01"}\n')
    with pytest.raises(fe.ResultsFileError, match=rf"p01_pair\.jsonl:{lines + 1}: not JSON"):
        fe.read_responses(log)


def test_an_output_folder_of_another_run_is_refused_unless_overwritten(tmp_path, capsys):
    """Old and new results are never mixed: a folder holding another run's files is refused,
    before anything is read or written; --overwrite replaces them (other files stay)."""
    csv_path = write_table(tmp_path, make_table("jod"))
    out = tmp_path / "study"
    argv = ["study", "--comparison", str(csv_path), "--observers", "2", "-o", str(out)]
    assert main(argv) == 0
    (out / "observers_responses.csv").write_text("a stale file of another kind of run\n")
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    capsys.readouterr()
    assert_refused(
        argv, r"-o .*study: holds another run's files \(.*\); choose a new folder, or --overwrite", capsys
    )
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    assert main([*argv, "--overwrite"]) == 0
    assert not (out / "observers_responses.csv").exists()  # the old run's, gone
    assert (out / "notes.txt").read_text() == "mine" and (out / "responses.csv").is_file()


# --- errors ---------------------------------------------------------------------------------


def test_missing_level_names_it_and_what_the_table_has(tmp_path, capsys):
    rows = [r for r in make_table("jod") if not (r["fovea_deg"] == 12.5 and r["spp"] == 4)]
    csv_path = write_table(tmp_path, rows)
    message = r"study level 12\.5/25 .*no rows at spp 4.*\[5/10, 7\.5/15, 10/20, 15/30\].*spp values \[1, 4\]"
    assert_refused(["study", "--comparison", str(csv_path), "-o", str(tmp_path / "out")], message, capsys)
    with pytest.raises(ValueError, match=r"no rows at spp 9 \(spp values: \[1, 4\]\)"):
        fe.difference_from_comparison(make_table("jod"), spp=9)


@pytest.mark.parametrize(
    ("metric", "table_metric", "message"),
    [
        ("jod", "flip", r"no column 'jod' \(columns: \[.*'flip'"),
        (None, None, r"neither a 'jod' nor a 'flip' column \(columns: \[.*'psnr'"),
    ],
)
def test_missing_metric_column_names_the_columns(tmp_path, capsys, metric, table_metric, message):
    rows = make_table(table_metric or "flip")
    if table_metric is None:
        rows = [{k: v for k, v in r.items() if k != "flip"} for r in rows]
    csv_path = write_table(tmp_path, rows)
    argv = ["study", "--comparison", str(csv_path), "-o", str(tmp_path / "out")]
    assert_refused(argv + ([] if metric is None else ["--metric", metric]), message, capsys)


@pytest.mark.parametrize("bad", [None, math.nan, math.inf, "n/a"])
def test_non_finite_metric_value_names_the_row(tmp_path, capsys, bad):
    rows = make_table("jod")
    index = next(i for i, r in enumerate(rows) if r["fovea_deg"] == 12.5 and r["spp"] == 4)
    rows[index]["jod"] = bad
    csv_path = write_table(tmp_path, rows)
    # FILE:LINE (the header is line 1): an empty cell when the study needs it, anything else at once.
    message = rf"{re.escape(str(csv_path))}:{index + 2}\b.*: jod is"
    assert_refused(["study", "--comparison", str(csv_path), "-o", str(tmp_path / "out")], message, capsys)
    # A bad value in a row the study does not use (spp 1) is no error to the API (the command
    # checks every row of the file it reads).
    rows[index]["jod"] = 9.3
    rows[index + 2]["jod"] = bad
    assert rows[index + 2]["spp"] == 1
    fe.difference_from_comparison(rows, spp=4)


def test_model_errors_name_the_models():
    rows = make_table("jod", models=("thesis", "other"))
    with pytest.raises(ValueError, match=r"several acuity models at spp 4: \['thesis', 'other'\]"):
        fe.difference_from_comparison(rows)
    with pytest.raises(ValueError, match=r"model 'gauss'.*\(models: \['thesis', 'other'\]\)"):
        fe.difference_from_comparison(rows, model="gauss")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "one of the arguments --comparison --responses --video is required"),
        (["--comparison", "c.csv", "--responses", "r.csv"], "not allowed with argument"),
        (["--comparison", "c.csv", "--observers", "0"], "argument --observers: must be >= 1"),
        (["--comparison", "c.csv", "--noise-sd", "-1"], "argument --noise-sd: must be a finite number >= 0"),
    ],
)
def test_argument_errors(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "r.csv").write_text(",".join(fe.RESULT_FIELDS) + "\n")
    with pytest.raises(SystemExit) as err:
        main(["study", *argv, "-o", str(tmp_path / "out")])
    assert err.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--responses", "nowhere.csv"], "--responses nowhere.csv: no such file or folder"),
        (["--responses", "empty"], "--responses empty: a folder without results files (.jsonl/.csv)"),
        (
            ["--comparison", "c.csv", "--beside", "c.csv"],
            "--beside: only with --responses (the observers are drawn beside people's answers)",
        ),
        (
            ["--responses", "r.csv", "--metric", "jod", "--seed", "3"],
            "--metric, --seed: only with --comparison (--responses files already hold the answers)",
        ),
        (["--comparison", "nowhere"], "--comparison nowhere: no such file or folder"),
        (
            ["--comparison", "empty"],
            "--comparison empty: a folder without comparison.csv (`fovjax compare -o`)",
        ),
        (["--responses", "r.csv", "--beside", "/missing"], "--beside /missing: no such file or folder"),
    ],
)
def test_bad_responses_are_one_line_errors(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.csv").write_text("fovea_deg,periphery_deg,spp,flip\n")
    (tmp_path / "r.csv").write_text(",".join(fe.RESULT_FIELDS) + "\n")
    (tmp_path / "empty").mkdir()
    assert main(["study", *argv, "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err == f"fovjax study: error: {message}\n"
    assert not (tmp_path / "out").exists()  # nothing written before every argument is checked


@pytest.mark.parametrize("regions", [None, "angle", "thesis"])
def test_study_says_when_the_thesis_column_is_not_like_for_like(tmp_path, capsys, regions):
    """The thesis's 12.5°/25° was found on its own regions; a table of exact-angle regions
    (fovjax compare's default, or an older table without the column) is flagged beside it."""
    rows = make_table("jod")
    if regions is not None:
        rows = [{**r, "regions": regions} for r in rows]
    argv = ["study", "--comparison", str(write_table(tmp_path, rows)), "-o", str(tmp_path / "out")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    flagged = "not the thesis's reading: the thesis column is not like-for-like" in out
    assert flagged == (regions != "thesis"), out
