"""The thesis's study protocols: the appendix's trial sequences, the results file, the automatic
observer's decisions on synthetic metric values, and the analysis behind figures 66-68."""

import json
import math

import imageio.v3 as iio
import pytest

import fovjax.eval as fe

# Transcribed from the thesis's appendix ("User Evaluation").
APPENDIX_PAIR = [
    (5.0, 10.0, "reference_first"),  # "First non-Foveated then Foveated"
    (5.0, 10.0, "foveated_first"),  # "First Foveated then non-Foveated"
    (7.5, 15.0, "reference_first"),
    (7.5, 15.0, "foveated_first"),
    (10.0, 20.0, "reference_first"),
    (10.0, 20.0, "foveated_first"),
    (12.5, 25.0, "reference_first"),
    (12.5, 25.0, "foveated_first"),
    (15.0, 30.0, "reference_first"),
    (15.0, 30.0, "foveated_first"),
]
APPENDIX_RAMP = [
    ("up", 5.0, 10.0),  # "Quality when Foveated circle increased", first to fifth sequence
    ("up", 7.5, 15.0),
    ("up", 10.0, 20.0),
    ("up", 12.5, 25.0),
    ("up", 15.0, 30.0),
    ("down", 15.0, 30.0),  # "Quality when Foveated circle Decreased"
    ("down", 12.5, 25.0),
    ("down", 10.0, 20.0),  # printed "Peripheral = 10°" in the appendix: a typo (see _protocols)
    ("down", 7.5, 15.0),
    ("down", 5.0, 10.0),
]


def test_pair_sequence_is_the_appendix():
    trials = fe.pair_trials()
    assert [(t.fovea_deg, t.periphery_deg, t.order) for t in trials] == APPENDIX_PAIR
    assert [t.index for t in trials] == list(range(10))
    assert all(t.test == "pair" and t.choices == ("first", "second", "same") for t in trials)
    assert trials[1].condition == "pair 5/10 foveated-first"


def test_ramp_sequence_is_the_appendix():
    trials = fe.ramp_trials()
    assert [(t.direction, t.fovea_deg, t.periphery_deg) for t in trials] == APPENDIX_RAMP
    assert [t.step for t in trials] == [0, 1, 2, 3, 4] * 2
    assert all(t.choices == ("increase", "decrease", "same") for t in trials)
    assert trials[7].condition == "ramp down step 2 10/20"


def test_slider_starts_at_the_lowest_level():
    trial = fe.slider_trial()
    assert (trial.test, trial.level) == ("slider", (5.0, 10.0))
    assert trial.choices == ("5", "7.5", "10", "12.5", "15")
    assert fe.slider_trial(start=2).level == (10.0, 20.0)
    with pytest.raises(ValueError, match="start 5"):
        fe.slider_trial(start=5)


def test_levels_are_the_thesis_pairs():
    assert fe.APPENDIX_LEVELS == ((5.0, 10.0), (7.5, 15.0), (10.0, 20.0), (12.5, 25.0), (15.0, 30.0))


def test_seeded_sequences():
    a, b = fe.pair_trials(seed=3), fe.pair_trials(seed=3)
    assert a == b  # reproducible
    assert sorted((t.fovea_deg, t.periphery_deg, t.order) for t in a) == sorted(APPENDIX_PAIR)  # same trials
    assert [t.index for t in a] == list(range(10))
    orders = {tuple(t.condition for t in fe.pair_trials(seed=s)) for s in range(5)}
    assert len(orders) > 1  # seeds give different orders
    ramps = [fe.ramp_trials(seed=s) for s in range(8)]
    firsts = {r[0].direction for r in ramps}
    assert firsts == {"up", "down"}  # some seeds put the downward ramp first...
    for r in ramps:  # ...but each ramp keeps its steps in order
        for direction in ("up", "down"):
            steps = [(t.step, t.fovea_deg) for t in r if t.direction == direction]
            assert [s for s, _ in steps] == [0, 1, 2, 3, 4]
            fovea = [f for _, f in steps]
            assert fovea == sorted(fovea, reverse=direction == "down")


def test_custom_levels_and_bad_levels():
    trials = fe.pair_trials([(4.0, 8.0), (6.0, 12.0)])
    assert [t.condition for t in trials][:2] == ["pair 4/8 reference-first", "pair 4/8 foveated-first"]
    with pytest.raises(ValueError, match="increasing order"):
        fe.ramp_trials([(6.0, 12.0), (4.0, 8.0)])
    with pytest.raises(ValueError, match="fovea <= periphery"):
        fe.pair_trials([(10.0, 5.0)])
    with pytest.raises(ValueError, match="must not be empty"):
        fe.pair_trials([])


def test_trial_and_response_validation():
    with pytest.raises(ValueError, match="pair trial needs order"):
        fe.Trial("pair", 0, 5.0, 10.0)
    with pytest.raises(ValueError, match="ramp trial needs direction"):
        fe.Trial("ramp", 0, 5.0, 10.0, direction="up")
    with pytest.raises(ValueError, match="test must be one of"):
        fe.Trial("staircase", 0, 5.0, 10.0)
    trial = fe.pair_trials()[0]
    with pytest.raises(ValueError, match="not one of"):
        fe.Response("p1", trial, "increase")
    with pytest.raises(ValueError, match="time_s"):
        fe.Response("p1", trial, "same", time_s=-1.0)


# --- the automatic observer --------------------------------------------------------------------

# A synthetic metric difference per fovea (e.g. 10 - JOD): visible below 12.5°, with a JND of 1.
D = {5.0: 3.0, 7.5: 2.0, 10.0: 1.2, 12.5: 0.6, 15.0: 0.2}


def by_fovea(table):
    return lambda trial: table[trial.fovea_deg]


def test_observer_pair_decisions():
    observer = fe.MetricObserver(by_fovea(D), threshold=1.0, name="auto")
    answers = [r.answer for r in observer.answer(fe.pair_trials())]
    # Seen below 12.5°: the reference is better, i.e. "first" when it came first.
    assert answers == ["first", "second"] * 3 + ["same", "same"] * 2


def test_observer_ramp_decisions():
    observer = fe.MetricObserver(by_fovea(D), threshold=1.0)
    answers = [r.answer for r in observer.answer(fe.ramp_trials())]
    assert answers == [
        "decrease",  # up 5°: seen, after the reference (d = 0): worse
        "increase",  # up 7.5°: seen, d 3.0 -> 2.0
        "increase",  # up 10°: seen, d 2.0 -> 1.2
        "same",  # up 12.5°: not seen
        "same",  # up 15°
        "same",  # down 15°
        "same",  # down 12.5°
        "decrease",  # down 10°: seen, d 0.6 -> 1.2
        "decrease",  # down 7.5°
        "decrease",  # down 5°
    ]


def test_observer_slider_decisions():
    observer = fe.MetricObserver(by_fovea(D), threshold=1.0)
    assert observer.answer([fe.slider_trial()])[0].answer == "12.5"
    # The first level not seen, walking up from the start, even if a later one is seen again.
    bumpy = {5.0: 3.0, 7.5: 0.5, 10.0: 2.0, 12.5: 0.1, 15.0: 0.1}
    assert fe.MetricObserver(by_fovea(bumpy), 1.0).answer([fe.slider_trial()])[0].answer == "7.5"
    assert fe.MetricObserver(by_fovea(bumpy), 1.0).answer([fe.slider_trial(start=2)])[0].answer == "12.5"
    # Every level seen: the slider's end.
    assert fe.MetricObserver(by_fovea(D), threshold=0.1).answer([fe.slider_trial()])[0].answer == "15"


def test_observer_threshold_is_strict_and_configurable():
    at = {f: 1.0 for f in D}
    same = fe.MetricObserver(by_fovea(at), threshold=1.0).answer(fe.pair_trials())
    assert {r.answer for r in same} == {"same"}  # d == threshold: not seen
    strict = fe.MetricObserver(by_fovea(at), threshold=0.999).answer(fe.pair_trials())
    assert "same" not in {r.answer for r in strict}
    # A lower threshold moves the slider's choice up.
    choices = [
        fe.MetricObserver(by_fovea(D), threshold=t).answer([fe.slider_trial()])[0].answer
        for t in (2.5, 1.5, 1.0, 0.5)
    ]
    assert choices == ["7.5", "10", "12.5", "15"]


def test_observer_sees_the_trial():
    seen = []

    def difference(trial):
        seen.append(trial.condition if trial.test != "slider" else trial.level)
        return 0.0

    fe.MetricObserver(difference, 1.0).answer([*fe.pair_trials()[:2], fe.slider_trial()])
    assert seen == ["pair 5/10 reference-first", "pair 5/10 foveated-first", (5.0, 10.0)]


def test_noisy_observer_follows_a_psychometric_function():
    # d exactly at the threshold: a difference is seen half the time.
    observer = fe.MetricObserver(lambda t: 1.0, threshold=1.0, noise_sd=0.5, seed=11)
    trials = fe.pair_trials() * 40
    answers = [r.answer for r in observer.answer(trials)]
    assert answers == [r.answer for r in observer.answer(trials)]  # seeded: reproducible
    assert 0.4 < answers.count("same") / len(answers) < 0.6
    # Far above the threshold (4 sd): practically always seen.
    sure = fe.MetricObserver(lambda t: 3.0, threshold=1.0, noise_sd=0.5, seed=11).answer(trials)
    assert sum(r.answer == "same" for r in sure) == 0


@pytest.mark.no_typecheck
def test_observer_rejects_bad_metric_values():
    with pytest.raises(ValueError, match="not a number"):
        fe.MetricObserver(lambda t: math.nan, 1.0).answer(fe.pair_trials())
    with pytest.raises(ValueError, match="callable"):
        fe.MetricObserver(1.0, 1.0)
    with pytest.raises(ValueError, match="noise_sd"):
        fe.MetricObserver(lambda t: 0.0, 1.0, noise_sd=-1)


def test_decision_rule_is_stated():
    for word in ("threshold", "pair", "ramp", "slider", "same", "increase", "decrease"):
        assert word in fe.DECISION_RULE


# --- results files -------------------------------------------------------------------------------


def human_answers():
    """Three made-up participants answering every test, with response times."""
    out = []
    pair_answers = {
        "p1": ["first", "second", "first", "second", "first", "same", "same", "same", "same", "same"],
        "p2": ["first", "second", "same", "second", "same", "same", "same", "same", "same", "same"],
        "p3": ["first", "first", "first", "second", "first", "second", "first", "same", "same", "same"],
    }
    ramp_answers = {
        "p1": [
            "decrease",
            "increase",
            "same",
            "same",
            "same",
            "same",
            "same",
            "same",
            "decrease",
            "decrease",
        ],
        "p2": [
            "decrease",
            "increase",
            "increase",
            "same",
            "same",
            "same",
            "same",
            "decrease",
            "decrease",
            "same",
        ],
        "p3": [
            "decrease",
            "decrease",
            "increase",
            "increase",
            "same",
            "same",
            "decrease",
            "decrease",
            "decrease",
            "decrease",
        ],
    }
    slider_answers = {"p1": "10", "p2": "12.5", "p3": "12.5"}
    for p in ("p1", "p2", "p3"):
        for k, (trial, answer) in enumerate(zip(fe.pair_trials(), pair_answers[p], strict=True)):
            out.append(fe.Response(p, trial, answer, time_s=1.0 + 0.25 * k))
        for trial, answer in zip(fe.ramp_trials(), ramp_answers[p], strict=True):
            out.append(fe.Response(p, trial, answer, time_s=2.5))
        out.append(fe.Response(p, fe.slider_trial(), slider_answers[p], time_s=40.0))
    return out


@pytest.mark.parametrize("suffix", [".csv", ".jsonl"])
def test_results_file_round_trip(tmp_path, suffix):
    answers = human_answers() + fe.MetricObserver(by_fovea(D), 1.0).answer(fe.study_trials(seed=2))
    path = fe.write_responses(answers, tmp_path / f"results{suffix}")
    assert fe.read_responses(path) == answers
    if suffix == ".csv":
        header = path.read_text().splitlines()[0]
        assert header == ",".join(fe.RESULT_FIELDS)
    else:
        row = json.loads(path.read_text().splitlines()[-1])
        assert row["test"] == "slider" and row["answer"] == "12.5" and row["time_s"] is None


def test_results_file_errors_name_file_line_and_field(tmp_path):
    good = fe.write_responses(human_answers()[:3], tmp_path / "r.csv").read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([good[0], good[1], good[2].replace(",second,", ",better,")]) + "\n")
    with pytest.raises(fe.ResultsFileError, match=r"bad\.csv:3: .*'better'"):
        fe.read_responses(bad)
    bad.write_text("\n".join([good[0], good[1].replace("5/10", "7.5/15")]) + "\n")
    with pytest.raises(fe.ResultsFileError, match=r"bad\.csv:2: condition"):
        fe.read_responses(bad)
    bad.write_text("\n".join([good[0], good[1].replace(",5.0,", ",five,", 1)]) + "\n")
    with pytest.raises(fe.ResultsFileError, match=r"bad\.csv:2: field 'fovea_deg'"):
        fe.read_responses(bad)
    jl = tmp_path / "bad.jsonl"
    jl.write_text('{"participant": "p1"}\n')
    with pytest.raises(fe.ResultsFileError, match=r"bad\.jsonl:1: missing columns"):
        fe.read_responses(jl)
    jl.write_text("not json\n")
    with pytest.raises(fe.ResultsFileError, match=r"bad\.jsonl:1: not JSON"):
        fe.read_responses(jl)
    with pytest.raises(ValueError, match="use a .csv or .jsonl"):
        fe.write_responses([], tmp_path / "r.txt")


# --- analysis (figures 66-68) -------------------------------------------------------------------


def test_wilson_interval():
    # 2 of 3 at 95%, by hand: centre (2/3 + z^2/6) / (1 + z^2/3) = 0.57308,
    # half-width z sqrt(2/27 + z^2/36) / (1 + z^2/3) = 0.36543 with z = 1.95996.
    lo, hi = fe.wilson_interval(2, 3)
    assert (lo, hi) == pytest.approx((0.20765, 0.93851), abs=1e-4)
    assert fe.wilson_interval(0, 10)[0] == 0.0 and fe.wilson_interval(10, 10)[1] == 1.0
    assert all(math.isnan(v) for v in fe.wilson_interval(0, 0))


def test_analyse_pair_on_synthetic_answers():
    rows = fe.analyse_pair(human_answers())
    assert [(r["fovea_deg"], r["periphery_deg"]) for r in rows] == list(fe.APPENDIX_LEVELS)
    # Per level, 3 participants x 2 orders = 6 answers. "same" counted by hand from human_answers:
    assert [r["same"] for r in rows] == [0, 1, 3, 5, 6]
    assert [r["answers"] for r in rows] == [6] * 5 and [r["participants"] for r in rows] == [3] * 5
    # 5°: p3 answered "first" when the foveated render came first: foveated judged better once.
    assert (rows[0]["reference_better"], rows[0]["foveated_better"]) == (5, 1)
    assert rows[3]["proportion_same"] == pytest.approx(5 / 6)
    lo, hi = fe.wilson_interval(5, 6)
    assert (rows[3]["proportion_same_lo"], rows[3]["proportion_same_hi"]) == (lo, hi)
    # 10°: 3 of 6 is exactly half, not a majority; 12.5° (5 of 6) is the first majority.
    assert rows[2]["proportion_same"] == 0.5
    assert fe.majority_level(rows) == 12.5


def test_analyse_ramp_and_slider_on_synthetic_answers():
    rows = fe.analyse_ramp(human_answers())
    up = [r for r in rows if r["direction"] == "up"]
    down = [r for r in rows if r["direction"] == "down"]
    assert [r["fovea_deg"] for r in up] == [5.0, 7.5, 10.0, 12.5, 15.0]
    assert [r["same"] for r in up] == [0, 0, 1, 2, 3]
    assert [r["same"] for r in down] == [1, 0, 1, 2, 3]  # listed by level: 5°, 7.5°, 10°, 12.5°, 15°
    assert [(r["increase"], r["decrease"]) for r in up][:2] == [(0, 3), (2, 1)]
    assert fe.majority_level(up) == 12.5 and fe.majority_level(down) == 12.5
    slider = fe.analyse_slider(human_answers())
    assert [r["participants"] for r in slider] == [0, 0, 1, 2, 0]
    assert slider[3]["proportion"] == pytest.approx(2 / 3)


def test_study_runs_programmatically_and_draws_figures(tmp_path):
    # Three automatic participants with different JNDs, each with its own trial order.
    observers = [fe.MetricObserver(by_fovea(D), threshold=t, name=f"auto-{t}") for t in (0.5, 1.0, 1.5)]
    responses = fe.run_study(observers, seed=100)
    assert len(responses) == 3 * (10 + 10 + 1)
    slider = fe.analyse_slider(responses)
    assert [r["participants"] for r in slider] == [0, 0, 1, 1, 1]  # 10°, 12.5°, 15°
    pair = fe.analyse_pair(responses)
    assert [r["same"] for r in pair] == [0, 0, 2, 4, 6]
    # The same analysis reads a results file of those answers.
    path = fe.write_responses(responses, tmp_path / "auto.jsonl")
    assert fe.analyse_pair(fe.read_responses(path)) == pair
    paths = fe.write_study_report(responses, tmp_path / "report")
    assert sorted(paths) == ["pair_csv", "pair_png", "ramp_csv", "ramp_png", "slider_csv", "slider_png"]
    assert paths["pair_png"].name == "fig66_pair_test.png"
    for key in ("pair_png", "ramp_png", "slider_png"):
        image = iio.imread(paths[key])
        assert image.shape[0] > 300 and image[..., :3].std() > 5
    assert fe.read_csv(paths["slider_csv"])[2] == {
        "fovea_deg": 10.0,
        "periphery_deg": 20.0,
        "participants": 1,
        "proportion": 1 / 3,
    }
