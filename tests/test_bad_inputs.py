"""Bad inputs to every `fovjax` command, one row each: the command line, the exit status, a piece
of the one-line message (the bad value), and no traceback. Rows run in-process through
`fovjax.cli.main`; the expensive entry points (BVH build, rendering, sessions, fits, sweeps) are
replaced by a trap, so a row passes only if its input is refused before any of that starts. A
few rows go through the real entry point (`python -m fovjax`), and Ctrl-C is sent to real
processes at the end."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import fovjax
import fovjax.acuity
import fovjax.eval
import fovjax.trace
from fovjax.cli import main
from fovjax.eval import APPENDIX_LEVELS

REPO = Path(__file__).resolve().parents[1]
CURVE = REPO / "data" / "mandelbaum" / "curve_samples.csv"
SCANPATH = REPO / "data" / "recordings" / "synthetic_scanpath_seed0.jsonl"
HEAD = REPO / "data" / "recordings" / "synthetic_head_sway.csv"
TINY = ["--scene", "cornell", "--width", "8", "--height", "8"]


class ExpensiveWork(BaseException):
    """Raised by the trapped entry points: `main` does not catch it, so the test fails loudly."""


def _trap(*args, **kwargs):
    raise ExpensiveWork("the command started expensive work before refusing its input")


@pytest.fixture(autouse=True)
def _traps(monkeypatch):
    for module, name in [
        (fovjax.trace, "build_bvh"),
        (fovjax, "run_session"),
        (fovjax.eval, "compare_thresholds"),
        (fovjax.eval, "failure_cases"),
        (fovjax.eval, "temporal_stability"),
        (fovjax.acuity, "fit"),
        (fovjax.acuity, "write_sweep"),
    ]:
        monkeypatch.setattr(module, name, _trap)


@pytest.fixture
def files(tmp_path):
    """Bad (and good) input files, by the {name} used in the rows."""
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"eccentricity_deg,acuity\n0,1\n\x89PNG\r\n\x1a\n\x00\x00")
    table = tmp_path / "comparison.csv"
    rows = ["config,fovea_deg,periphery_deg,spp,flip"]
    for fovea, periphery in APPENDIX_LEVELS:
        flip = -0.2 if fovea == 12.5 else 0.01
        rows.append(f"{fovea:g}/{periphery:g} spp4,{fovea},{periphery},4,{flip}")
    table.write_text("\n".join(rows) + "\n")
    jod = tmp_path / "jod.csv"
    jod.write_text(table.read_text().replace("flip", "jod").replace("-0.2", "10.5").replace("0.01", "9.5"))
    # Comparison tables each with one bad cell on line 4 (the level 10/20 row), or a bad header.
    lines = table.read_text().splitlines()
    bad_tables = {}
    for name, (column, value) in {
        "fovea_five": ("fovea_deg", "five"),
        "periphery_small": ("periphery_deg", "2"),
        "fovea_negative": ("fovea_deg", "-10"),
        "spp_four": ("spp", "four"),
        "spp_half": ("spp", "4.5"),
        "spp_zero": ("spp", "0"),
        "flip_text": ("flip", "low"),
        "flip_inf": ("flip", "inf"),
    }.items():
        header = lines[0].split(",")
        cells = lines[3].split(",")
        cells[header.index(column)] = value
        path = tmp_path / f"{name}.csv"
        path.write_text("\n".join([*lines[:3], ",".join(cells), *lines[4:]]) + "\n")
        bad_tables[name] = str(path)
    good_table = tmp_path / "good_table.csv"
    good_table.write_text(table.read_text().replace("-0.2", "0.01"))
    short_row = tmp_path / "short_row.csv"
    short_row.write_text("\n".join([*lines[:3], "10/20 spp4,10,20,4", *lines[4:]]) + "\n")
    no_spp = tmp_path / "no_spp.csv"
    no_spp.write_text(table.read_text().replace(",spp,", ",samples,"))
    no_metric = tmp_path / "no_metric.csv"
    no_metric.write_text(table.read_text().replace(",flip", ",psnr"))
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    fit_five = tmp_path / "fit_five.csv"
    fit_five.write_text("eccentricity_deg,acuity,sd,n,condition,source\n0,1,,,c,s\nfive,0.5,,,c,s\n")
    responses_five = tmp_path / "responses_five.csv"
    responses_five.write_text(
        "participant,test,trial,condition,fovea_deg,periphery_deg,order,direction,step,answer,time_s\n"
        "p1,pair,1,x,five,10,,,,same,\n"
    )
    recording_five = tmp_path / "recording_five.csv"
    recording_five.write_text(
        "t,device_time,lx,ly,lq,lv,rx,ry,rq,rv\n0,0,0.5,0.5,1,1,0.5,0.5,1,1\n0.1,0.1,five,0.5,1,1,0.5,0.5,1,1\n"
    )
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    recording_bin = tmp_path / "bin.jsonl"
    recording_bin.write_bytes(b'{"fovjax_recording": 1, "kind": "gaze"}\n\xff\xfe\n')
    scene_txt = tmp_path / "scene.txt"
    scene_txt.write_text("v 0 0 0\n")
    bad_hdr = tmp_path / "sky.hdr"
    bad_hdr.write_text("not an image")
    not_recording = tmp_path / "table.csv"
    not_recording.write_text("a,b\n1,2\n")
    empty_dir = tmp_path / "empty_dir"
    empty_dir.mkdir()
    short_vertex = tmp_path / "short.obj"
    short_vertex.write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n")
    garbage = tmp_path / "garbage.csv"
    garbage.write_text("garbage line here\nmore garbage\n")
    repeated = tmp_path / "repeated.csv"
    repeated.write_text("eccentricity_deg,acuity,acuity\n0,1,1\n")
    old_session = tmp_path / "old_session"  # another run's session folder
    old_session.mkdir()
    for name in ("frame_00000.png", "frame_00001.png", "frame_00002.png", "session.csv"):
        (old_session / name).write_bytes(b"")
    old_compare = tmp_path / "old_compare"
    old_compare.mkdir()
    (old_compare / "cost_accuracy_ms_spp16.png").write_bytes(b"")
    old_study = tmp_path / "old_study"
    old_study.mkdir()
    (old_study / "timing.csv").write_text("file\n")
    old_failures = tmp_path / "old_failures"
    old_failures.mkdir()
    (old_failures / "findings.csv").write_text("case\n")
    return {
        "curve": str(CURVE),
        "scanpath": str(SCANPATH),
        "head_rec": str(HEAD),
        "binary": str(binary),
        "table": str(table),
        "jod": str(jod),
        "a_file": str(a_file),
        "unwritable": str(a_file / "out.png"),
        "unwritable_dir": str(a_file / "out"),
        "recording_bin": str(recording_bin),
        "scene_txt": str(scene_txt),
        "bad_hdr": str(bad_hdr),
        "not_recording": str(not_recording),
        "tmp": str(tmp_path),
        "empty_dir": str(empty_dir),
        **bad_tables,
        "good_table": str(good_table),
        "short_row": str(short_row),
        "no_spp": str(no_spp),
        "no_metric": str(no_metric),
        "empty": str(empty),
        "fit_five": str(fit_five),
        "responses_five": str(responses_five),
        "recording_five": str(recording_five),
        "short_vertex": str(short_vertex),
        "garbage": str(garbage),
        "repeated": str(repeated),
        "old_session": str(old_session),
        "old_compare": str(old_compare),
        "old_study": str(old_study),
        "old_failures": str(old_failures),
    }


# A frame no machine has the memory for (2 x 10^12 pixels): refused by the size check.
HUGE = "--width 1000000 --height 1000000"


# (command line, exit status, a piece of the message); {name} is a file of the `files` fixture.
ROWS = [
    # -- render ------------------------------------------------------------------------------
    ("render --exposure nan", 2, "--exposure nan"),
    ("render --exposure -1", 2, "--exposure -1"),
    ("render --exposure 0", 2, "expected a finite number > 0"),
    ("render --spp 3", 2, "--spp 3: expected a perfect square"),
    ("render --spp 0", 2, "--spp 0"),
    ("render --width 0", 2, "--width 0"),
    ("render --height -5", 2, "--height -5"),
    ("render --max-depth -1", 2, "--max-depth -1"),
    ("render --triangles 0", 2, "--triangles 0"),
    ("render --fovea 10 --periphery 5", 2, "must not be smaller than the fovea"),
    ("render --fovea -1", 2, "fovea -1"),
    ("render --fovea nan", 2, "fovea nan"),
    ("render --periphery inf", 2, "periphery inf"),
    ("render --gaze 0.5,0.5,1.5,0.5", 2, "1.5"),
    ("render --gaze nan,0.5,0.5,0.5", 2, "nan"),
    ("render --head 0,nan,0", 2, "--head pitch nan"),
    ("render --head 1,2", 2, "YAW,PITCH,ROLL"),
    ("render --scene nowhere", 2, "'nowhere'"),
    ("render --scene nowhere.obj", 2, "'nowhere.obj': not a built-in scene"),
    ("render --scene {scene_txt}", 2, "scene.txt"),
    ("render --scene {empty_dir}", 2, "the folder holds no scene file"),
    ("render --envmap /no/such/sky.hdr", 2, "/no/such/sky.hdr: no such file"),
    ("render --envmap {bad_hdr}", 2, "--envmap {bad_hdr}: load_image"),
    ("render -o out.jpg", 2, "unknown output type '.jpg'"),
    ("render -o out", 2, "'(no suffix)'"),
    ("render -o {unwritable}", 2, "is a file, not a folder"),
    ("render -o {tmp}", 2, "is a folder"),
    ("render --preview -o x.exr", 2, "'.exr'"),
    ("render --backend optix", 2, "invalid choice: 'optix'"),
    ("render --tonemap aces", 2, "invalid choice: 'aces'"),
    ("render --spp two", 2, "invalid int value: 'two'"),
    ("render --seed -1", 2, "--seed -1"),
    ("render --seed 99999999999999999999", 2, "--seed 99999999999999999999"),
    ("bogus-command", 2, "invalid choice: 'bogus-command'"),
    (f"render {HUGE}", 2, "--width/--height 1000000x1000000: a foveated frame of 2 x 1000000x1000000"),
    (f"render --full {HUGE}", 2, "a full frame of 2 x 1000000x1000000 pixels at SPP 1 needs about"),
    (f"render --mono {HUGE}", 2, "a full frame of 1000000x1000000 pixels at SPP 1 needs about"),
    ("render --scene cornell --width 8192 --height 8192 --spp 10000", 2, "8192x8192: a foveated frame"),
    ("render --scene {short_vertex} --mono", 2, "short.obj:2: 'v' line needs at least 3 numbers: 'v 1 0'"),
    # -- inspect -----------------------------------------------------------------------------
    ("inspect nowhere", 2, "SCENE 'nowhere': not a built-in scene"),
    ("inspect {scene_txt}", 2, "scene.txt"),
    ("inspect cornell --width 0", 2, "--width 0"),
    ("inspect cornell --max-depth -1", 2, "--max-depth -1"),
    ("inspect cornell --ring 0", 2, "--ring 0"),
    ("inspect cornell --ring nan", 2, "--ring nan"),
    ("inspect cornell --spp 2", 2, "--spp 2: expected a perfect square"),
    ("inspect cornell --fovea 10 --periphery 5", 2, "must not be smaller than the fovea"),
    ("inspect cornell --gaze 0.5,0.5,1.5,0.5", 2, "1.5"),
    ("inspect cornell --head 0,inf,0", 2, "--head pitch inf"),
    ("inspect cornell --triangles 0", 2, "--triangles 0"),
    ("inspect", 2, "the following arguments are required: scene"),
    (f"inspect cornell {HUGE}", 2, "--width/--height 1000000x1000000: a full frame"),
    # -- build -------------------------------------------------------------------------------
    ("build atrium", 2, "unrecognized arguments: atrium"),
    # -- session -----------------------------------------------------------------------------
    ("session --gaze bogus:thing --frames 2 -o {tmp}/s", 2, "unknown scheme 'bogus'"),
    ("session --gaze synthetic:spiral --frames 2 -o {tmp}/s", 2, "'spiral'"),
    ("session --gaze replay:/no/such.jsonl --frames 2 -o {tmp}/s", 2, "/no/such.jsonl"),
    ("session --gaze replay:{recording_bin} --frames 2 -o {tmp}/s", 2, "bin.jsonl:2"),
    ("session --gaze replay:{scanpath}@-2 --frames 2 -o {tmp}/s", 2, "'-2'"),
    ("session --gaze replay:{head_rec} --frames 2 -o {tmp}/s", 2, "is a head recording, not gaze"),
    ("session --gaze synthetic:fixed:0.5,nan --frames 2 -o {tmp}/s", 2, "0.5,nan"),
    ("session --gaze serial:/dev/ttyS0@fast --frames 2 -o {tmp}/s", 2, "baud rate 'fast'"),
    ("session --gaze pupil:host:99999 --frames 2 -o {tmp}/s", 2, "'99999'"),
    ("session --gaze pupil:bad_host! --frames 2 -o {tmp}/s", 2, "'bad_host!'"),
    ("session --gaze synthetic:scanpath --head pupil:x:1 --frames 2 -o {tmp}/s", 2, "Pupil gives gaze"),
    ("session --gaze synthetic:scanpath --frames 0 -o {tmp}/s", 2, "--frames 0"),
    ("session --gaze synthetic:scanpath --seconds nan -o {tmp}/s", 2, "--seconds nan"),
    ("session --gaze synthetic:scanpath --seconds 0.001 -o {tmp}/s", 2, "shorter than one frame"),
    ("session --gaze synthetic:scanpath --frames 2 --fps 0 -o {tmp}/s", 2, "--fps 0"),
    ("session --gaze synthetic:scanpath --frames 2 --fps inf -o {tmp}/s", 2, "--fps inf"),
    ("session --gaze synthetic:scanpath --frames 2 --spp 2 -o {tmp}/s", 2, "--spp 2"),
    ("session --gaze synthetic:scanpath --frames 2 --width 0 -o {tmp}/s", 2, "--width 0"),
    ("session --gaze synthetic:scanpath --frames 2 --fovea 20 --periphery 10 -o {tmp}/s", 2, "20,10"),
    ("session --gaze synthetic:scanpath --frames 2 --hold-for -1 -o {tmp}/s", 2, "--hold-for -1"),
    ("session --gaze synthetic:scanpath --frames 2 --widen-every 0 -o {tmp}/s", 2, "--widen-every 0"),
    ("session --gaze synthetic:scanpath --frames 2 --widen-steps 0 -o {tmp}/s", 2, "--widen-steps 0"),
    ("session --gaze synthetic:scanpath --frames 2 --wait 0 -o {tmp}/s", 2, "--wait 0"),
    ("session --gaze synthetic:scanpath --frames 2 --scene nowhere -o {tmp}/s", 2, "'nowhere'"),
    ("session --gaze synthetic:scanpath --frames 2 -o {a_file}", 2, "not a folder"),
    ("session --gaze synthetic:scanpath --frames 2 -o {unwritable_dir}", 2, "is a file, not a folder"),
    ("session --gaze synthetic:scanpath --frames 2 --seconds 1 -o {tmp}/s", 2, "not allowed with"),
    (f"session --gaze synthetic:fixed --frames 2 {HUGE} -o {{tmp}}/s", 2, "1000000x1000000: a foveated"),
    (
        "session --gaze synthetic:fixed --frames 2 -o {old_session}",
        2,
        "-o {old_session}: holds another run's files (frame_00000.png, frame_00001.png, frame_00002.png "
        "and 1 more); choose a new folder, or --overwrite to replace them",
    ),
    # -- record ------------------------------------------------------------------------------
    ("record --gaze serial:/dev/ttyNOPE --seconds 2 --wait 0.3 -o {tmp}/r.jsonl", 1, "/dev/ttyNOPE"),
    ("record --gaze pupil:127.0.0.1:9 --seconds 2 --wait 0.3 -o {tmp}/r.jsonl", 1, "127.0.0.1:9"),
    ("record --gaze pupil:notaport.invalid --wait 0.3 -o {tmp}/r.jsonl", 1, "pupil:notaport.invalid"),
    ("record --head intersense:/no/libisense.so -o {tmp}/r.csv", 1, "/no/libisense.so"),
    ("record --gaze viewpoint:/no/libvpx.so -o {tmp}/r.csv", 1, "/no/libvpx.so"),
    ("record --gaze synthetic:scanpath --seconds -1 -o {tmp}/r.jsonl", 2, "--seconds -1"),
    ("record --gaze synthetic:scanpath --seconds nan -o {tmp}/r.jsonl", 2, "--seconds nan"),
    ("record --gaze synthetic:scanpath --samples 0 -o {tmp}/r.jsonl", 2, "--samples 0"),
    ("record --gaze synthetic:scanpath --rate 0 -o {tmp}/r.jsonl", 2, "--rate 0"),
    ("record --gaze synthetic:scanpath --wait -3 -o {tmp}/r.jsonl", 2, "--wait -3"),
    ("record --gaze synthetic:scanpath --dropout soon -o {tmp}/r.jsonl", 2, "'soon'"),
    ("record --gaze synthetic:scanpath --dropout 3:1 -o {tmp}/r.jsonl", 2, "'3:1'"),
    ("record --gaze replay:{scanpath} --dropout 1:2 -o {tmp}/r.jsonl", 2, "synthetic gaze sources only"),
    ("record --gaze synthetic:scanpath -o {tmp}/r.txt", 2, "'.txt'"),
    ("record --gaze synthetic:scanpath -o {unwritable}.csv", 2, "is a file, not a folder"),
    ("record --head synthetic:nod -o {tmp}/r.jsonl", 2, "must be 'sway'"),
    ("record --gaze synthetic:scanpath:x -o {tmp}/r.jsonl", 2, "'x' is not an integer"),
    ("record --gaze synthetic:scanpath:-3 -o {tmp}/r.jsonl", 2, "seed '-3' must be >= 0"),
    ("record --gaze replay: -o {tmp}/r.jsonl", 2, "replay needs a file"),
    ("record --gaze replay:{binary} -o {tmp}/r.jsonl", 2, "binary.csv:3: not a text recording"),
    ("record --gaze replay:{not_recording} -o {tmp}/r.jsonl", 2, "gaze or a head recording"),
    ("record --gaze replay:{scanpath}@0 -o {tmp}/r.jsonl", 2, "replay speed '0'"),
    ("record --gaze serial: -o {tmp}/r.jsonl", 2, "serial needs a port"),
    ("record --gaze serial:/dev/x@-9600 -o {tmp}/r.jsonl", 2, "'-9600'"),
    ("record -o {tmp}/r.jsonl", 2, "one of the arguments --gaze --head is required"),
    # -- fit ---------------------------------------------------------------------------------
    ("fit {binary} -o {tmp}/f", 2, "binary.csv:3: not a text file"),
    ("fit /no/such.csv -o {tmp}/f", 2, "/no/such.csv: no such file"),
    ("fit {tmp} -o {tmp}/f", 2, "is a folder"),
    ("fit {scene_txt} -o {tmp}/f", 2, "'.txt'"),
    ("fit {curve} --fix zz=1 -o {tmp}/f", 2, "--fix zz=1"),
    ("fit {curve} --fix a=nan -o {tmp}/f", 2, "--fix a nan"),
    ("fit {curve} --fix a=1 --fix b=1 --fix c=1 -o {tmp}/f", 2, "every parameter"),
    ("fit {curve} --fix a -o {tmp}/f", 2, "NAME=VALUE"),
    ("fit {curve} --plot-max -5 -o {tmp}/f", 2, "--plot-max -5"),
    ("fit {curve} --plot-max 0 -o {tmp}/f", 2, "--plot-max 0"),
    ("fit {curve} --mar-reference -1 -o {tmp}/f", 2, "--mar-reference '-1'"),
    ("fit {curve} --mar-reference arcmin -o {tmp}/f", 2, "'arcmin'"),
    ("fit {curve} --posterior --nsteps 0 -o {tmp}/f", 2, "--nsteps 0"),
    ("fit {curve} --posterior --nwalkers 2 -o {tmp}/f", 2, "--nwalkers"),
    ("fit {curve} --posterior bootstrap --n-boot 0 -o {tmp}/f", 2, "--n-boot 0"),
    ("fit {curve} --nsteps -5 -o {tmp}/f", 2, "--nsteps -5"),
    ("fit {curve} --seed -2 -o {tmp}/f", 2, "--seed -2"),
    ("fit-stability --seed -1 -o {tmp}/fs", 2, "--seed -1"),
    ("fit {curve} --model gauss -o {tmp}/f", 2, "invalid choice: 'gauss'"),
    ("fit {curve} --condition scotopic -o {tmp}/f", 2, "--condition 'scotopic'"),
    ("fit {curve} -o {unwritable_dir}", 2, "is a file, not a folder"),
    ("fit-stability -o {a_file}", 2, "not a folder"),
    ("fit {garbage} -o {tmp}/f", 2, "{garbage}:1: missing column(s) ['eccentricity_deg', 'acuity']"),
    ("fit {repeated} -o {tmp}/f", 2, "{repeated}:1: repeated column(s) ['acuity']"),
    # -- compare -----------------------------------------------------------------------------
    ("compare --criterion bogus -o {tmp}/c", 2, "--criterion 'bogus'"),
    ("compare --thresholds 10,5 -o {tmp}/c", 2, "--thresholds 10,5"),
    ("compare --thresholds 5,10 nan,20 -o {tmp}/c", 2, "fovea nan"),
    ("compare --thresholds 5 -o {tmp}/c", 2, "FOVEA,PERIPHERY"),
    ("compare --gazes 0.5 -o {tmp}/c", 2, "a gaze point is X,Y in normalised display coordinates"),
    (f"compare {HUGE} -o {{tmp}}/c", 2, "--width/--height 1000000x1000000: a"),
    ("compare -o {old_compare}", 2, "holds another run's files (cost_accuracy_ms_spp16.png)"),
    ("compare --spp 3 -o {tmp}/c", 2, "--spp 3"),
    ("compare --spp 1 8 -o {tmp}/c", 2, "--spp 8"),
    ("compare --gazes 0.5,1.2 -o {tmp}/c", 2, "1.2"),
    ("compare --width 0 -o {tmp}/c", 2, "--width 0"),
    ("compare --frames 4 -o {tmp}/c", 2, "--frames needs --video"),
    ("compare --video {tmp}/missing.csv -o {tmp}/c", 2, "no such file"),
    ("compare --threshold nan -o {tmp}/c", 2, "nan"),
    ("compare --criterion flip --threshold 2 -o {tmp}/c", 2, "--threshold (of flip) 2"),
    ("compare --criterion ssim --threshold -3 -o {tmp}/c", 2, "-3"),
    ("compare --criterion jod --no-perceptual -o {tmp}/c", 2, "--criterion jod"),
    ("compare --max-depth -2 -o {tmp}/c", 2, "--max-depth -2"),
    ("compare --keys 0 -4 -o {tmp}/c", 2, "--keys -4"),
    ("compare --scene nowhere -o {tmp}/c", 2, "'nowhere'"),
    ("compare -o {a_file}", 2, "not a folder"),
    ("compare --distributed nohost,2,5 -o {tmp}/c", 2, "nohost,2,5"),
    ("compare --fidelity manual -o {tmp}/c", 2, "--fidelity 'manual'"),
    (
        "compare --fidelity auto --fidelity-threshold 2 -o {tmp}/c",
        2,
        "--fidelity-threshold (FLIP added per ring) 2",
    ),
    ("compare --fidelity auto --fidelity-threshold nan -o {tmp}/c", 2, "nan"),
    ("compare --fidelity-threshold -0.5 -o {tmp}/c", 2, "-0.5"),
    (
        "compare --fidelity auto --fidelity-frame-tolerance -0.01 -o {tmp}/c",
        2,
        "--fidelity-frame-tolerance (FLIP added to the frame) -0.01: expected a finite number >= 0",
    ),
    ("compare --fidelity auto --fidelity-frame-tolerance inf -o {tmp}/c", 2, "--fidelity-frame-tolerance"),
    ("compare --fidelity-frame-tolerance 0.005 -o {tmp}/c", 2, "0.005: bounds a plan, needs --fidelity auto"),
    # -- study -------------------------------------------------------------------------------
    ("study --comparison {table} --metric flip -o {tmp}/st", 2, "flip is -0.2, outside its scale [0, 1]"),
    ("study --comparison {jod} --metric jod -o {tmp}/st", 2, "jod is 10.5, outside its scale"),
    ("study --comparison {binary} -o {tmp}/st", 2, "binary.csv:3: not a text file"),
    ("study --comparison /no/such.csv -o {tmp}/st", 2, "/no/such.csv: no such file"),
    ("study --comparison {table} --threshold -1 -o {tmp}/st", 2, "--threshold -1"),
    ("study --comparison {table} --spp 3 -o {tmp}/st", 2, "--spp 3"),
    ("study --comparison {good_table} --spp 9 -o {tmp}/st", 2, "no rows at spp 9"),
    ("study --comparison {table} --observers 0 -o {tmp}/st", 2, "--observers: must be >= 1"),
    ("study --comparison {table} --noise-sd nan -o {tmp}/st", 2, "'nan'"),
    ("study --comparison {table} --metric psnr -o {tmp}/st", 2, "invalid choice: 'psnr'"),
    ("study --comparison {table} --seed -7 -o {tmp}/st", 2, "--seed -7"),
    ("study --comparison {table} -o {a_file}", 2, "not a folder"),
    ("study --responses {binary} -o {tmp}/st", 2, "binary.csv:3: not a text file"),
    ("study --responses {scene_txt} -o {tmp}/st", 2, "'.txt'"),
    ("study --comparison {scanpath} -o {tmp}/st", 2, "a '.jsonl' file; expected comparison.csv"),
    ("study --comparison {old_failures} -o {tmp}/st", 2, "a folder without comparison.csv"),
    ("study --responses {garbage} -o {tmp}/st", 2, "{garbage}:1: missing columns ['participant'"),
    ("study --comparison {good_table} -o {old_study}", 2, "holds another run's files (timing.csv)"),
    (f"study --video {HUGE} -o {{tmp}}/st", 2, "1000000x1000000: a"),
    # every cell of a comparison table the study reads, FILE:LINE (issue 28: "five" was accepted)
    ("study --comparison {fovea_five} -o {tmp}/st", 2, "{fovea_five}:4: fovea_deg is 'five', not a number"),
    (
        "study --comparison {periphery_small} -o {tmp}/st",
        2,
        "{periphery_small}:4: fovea_deg 10.0, periphery_deg 2: expected 0 <= fovea",
    ),
    (
        "study --comparison {fovea_negative} -o {tmp}/st",
        2,
        "{fovea_negative}:4: fovea_deg -10, periphery_deg 20.0: expected 0 <= fovea",
    ),
    ("study --comparison {spp_four} -o {tmp}/st", 2, "{spp_four}:4: spp is 'four', not a whole number"),
    ("study --comparison {spp_half} -o {tmp}/st", 2, "{spp_half}:4: spp is '4.5', not a whole number"),
    ("study --comparison {spp_zero} -o {tmp}/st", 2, "{spp_zero}:4: spp is '0', not a whole number >= 1"),
    ("study --comparison {flip_text} -o {tmp}/st", 2, "{flip_text}:4: flip is 'low', not a number"),
    ("study --comparison {flip_inf} -o {tmp}/st", 2, "{flip_inf}:4: flip is 'inf', not a number"),
    ("study --comparison {table} -o {tmp}/st", 2, "{table}:5: flip is -0.2, outside its scale [0, 1]"),
    ("study --comparison {short_row} -o {tmp}/st", 2, "{short_row}:4: 4 fields, the header has 5"),
    ("study --comparison {no_spp} -o {tmp}/st", 2, "{no_spp}:1: no column 'spp'"),
    ("study --comparison {no_metric} -o {tmp}/st", 2, "{no_metric}:1: neither a 'jod' nor a 'flip' column"),
    ("study --comparison {empty} -o {tmp}/st", 2, "{empty}:1: empty file"),
    ("study --responses {responses_five} -o {tmp}/st", 2, "{responses_five}:2: field 'fovea_deg': bad value"),
    ("fit {fit_five} -o {tmp}/f", 2, "{fit_five}:3: eccentricity_deg = 'five' is not a number"),
    ("view --gaze replay:{recording_five}", 2, "{recording_five}:3: field lx='five' is not a number"),
    # -- failures / stability ----------------------------------------------------------------
    ("failures --cases nothing", 2, "invalid choice: 'nothing'"),
    ("failures --spp 1 5 -o {tmp}/fl", 2, "--spp 5"),
    ("failures --width -1 -o {tmp}/fl", 2, "--width -1"),
    ("failures --fovea 30 --periphery 20 -o {tmp}/fl", 2, "30,20"),
    ("failures --small 0x10 -o {tmp}/fl", 2, "'0x10'"),
    ("failures -o {a_file}", 2, "not a folder"),
    ("stability --frames 1 -o {tmp}/sb", 2, "--frames 1"),
    ("stability --fps -90 -o {tmp}/sb", 2, "--fps -90"),
    ("stability --scene nowhere -o {tmp}/sb", 2, "'nowhere'"),
    ("stability --max-depth -1 -o {tmp}/sb", 2, "--max-depth -1"),
    ("stability --seed -1 -o {tmp}/sb", 2, "--seed -1"),
    (f"failures {HUGE} -o {{tmp}}/fl", 2, "1000000x1000000: a foveated frame"),
    ("failures --small 100000x100000 --spp 1 10000 -o {tmp}/fl", 2, "--small 100000x100000: a"),
    ("failures -o {old_failures}", 2, "holds another run's files (findings.csv)"),
    (f"stability {HUGE} -o {{tmp}}/sb", 2, "1000000x1000000: a"),
    # -- view --------------------------------------------------------------------------------
    ("view --width 0", 2, "--width 0"),
    ("view --height 100000", 2, "--height 100000"),
    ("view --width 8192 --height 8192 --spp 10000", 2, "--width/--height 8192x8192: a foveated frame"),
    ("view --spp 3", 2, "--spp 3: expected a perfect square"),
    ("view --fovea nan", 2, "--fovea nan"),
    ("view --fovea 0", 2, "--fovea 0"),
    ("view --periphery 200", 2, "--periphery 200"),
    ("view --fovea 12 --periphery 10", 2, "the fovea must be smaller than the periphery"),
    ("view --max-depth -1", 2, "--max-depth -1"),
    ("view --triangles 0", 2, "--triangles 0"),
    ("view --seed -1", 2, "--seed -1"),
    ("view --port 70000", 2, "--port 70000"),
    ("view --port -1", 2, "--port -1"),
    ("view --port 0 --host 192.0.2.1", 2, "cannot listen on 192.0.2.1:0"),
    ("view --scene nowhere", 2, "'nowhere'"),
    ("view --scene {scene_txt}", 2, "scene.txt"),
    ("view --gaze telepathy:1", 2, "unknown scheme 'telepathy'"),
    ("view --gaze replay:{recording_bin}", 2, "bin.jsonl:2"),
    ("view --gaze replay:{head_rec}", 2, "is a head recording, not gaze"),
    ("view --head synthetic:nod", 2, "must be 'sway'"),
    ("view --save-dir {a_file}", 2, "not a folder"),
    ("view --save-dir {unwritable_dir}", 2, "is a file, not a folder"),
    ("view --backend optix", 2, "invalid choice: 'optix'"),
    ("view --spp two", 2, "invalid int value: 'two'"),
]


def _argv(row: str, files: dict) -> list[str]:
    return [part.format(**files) for part in row.split()]


@pytest.mark.parametrize(("row", "status", "message"), ROWS, ids=[r[0] for r in ROWS])
def test_bad_input_is_refused_with_one_line(row, status, message, files, capsys, monkeypatch):
    monkeypatch.chdir(files["tmp"])
    t0 = time.monotonic()
    try:
        got = main(_argv(row, files))
    except SystemExit as exit_:  # argparse's own errors
        got = exit_.code
    seconds = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert got == status, (out, err)
    message = message.format(**files)
    assert message in err, err
    assert "Traceback" not in out + err
    # One line of error (argparse adds its usage lines before its own).
    assert len([line for line in err.splitlines() if "error:" in line]) == 1, err
    assert seconds < 60, "a refused input must not wait on anything"  # generous: only catches hangs


def test_every_command_has_rows():
    from fovjax.cli import build_parser

    commands = set(build_parser()._subparsers._group_actions[0].choices)
    covered = {row.split()[0] for row, _, _ in ROWS}
    assert commands - {"bogus-command"} <= covered, commands - covered


def test_a_frame_too_large_names_the_size_the_estimate_and_the_limit(capsys):
    assert main(["render", *HUGE.split()]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(
        r"fovjax render: error: --width/--height 1000000x1000000: a foveated frame of 2 x 1000000x1000000 "
        r"pixels at SPP 1 needs about [\d.]+ TB, more than the [\d.]+ [GMT]B (available on this machine|free "
        r"under this process's memory limit \(cgroup\)|free on the .*); make it smaller, or set "
        r"FOVJAX_SIZE_CHECK=0 \(--no-size-check\) on a machine that has the memory\n",
        err,
    ), err


def test_the_size_check_can_be_turned_off(files, monkeypatch):
    """--no-size-check lets the frame through the command's check and the library's (StereoRig,
    FoveatedRenderer): the command goes on to build the BVH (the trap here)."""
    monkeypatch.delenv("FOVJAX_SIZE_CHECK", raising=False)
    argv = ["session", "--gaze", "synthetic:fixed", "--frames", "2", "--scene", "cornell", *HUGE.split()]
    with pytest.raises(ExpensiveWork):
        main([*argv, "-o", f"{files['tmp']}/s", "--no-size-check"])
    assert "FOVJAX_SIZE_CHECK" not in os.environ  # for the command only
    assert not Path(files["tmp"], "s").exists()


def test_overwrite_lets_a_run_into_a_folder_of_another(files):
    """With --overwrite the old session's folder is accepted, and its files are gone by the
    time the session starts (the trap here)."""
    folder = Path(files["old_session"])
    (folder / "notes.txt").write_text("mine")
    argv = ["session", "--gaze", "synthetic:fixed", "--frames", "2", "--scene", "cornell"]
    with pytest.raises(ExpensiveWork):
        main([*argv, "-o", str(folder), "--overwrite"])
    assert [p.name for p in folder.iterdir()] == ["notes.txt"]


def test_clear_outputs_removes_only_the_commands_files(tmp_path):
    from fovjax.cli import clear_outputs
    from fovjax.cli._session import SESSION_FILES

    for name in ("frame_00000.png", "debug_00003.png", "session.json", "notes.txt", "frame_x.jpg"):
        (tmp_path / name).write_text("")
    removed = clear_outputs(tmp_path, SESSION_FILES)
    assert [p.name for p in removed] == ["debug_00003.png", "frame_00000.png", "session.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_x.jpg", "notes.txt"]


@pytest.mark.parametrize("where", [0, -1])
def test_debug_shows_the_traceback(where):
    argv = ["render", "--exposure", "nan"]
    argv.insert(where if where == 0 else len(argv), "--debug")
    with pytest.raises(ValueError, match="--exposure nan"):
        main(argv)


# -- the real entry point --------------------------------------------------------------------
def _env():
    return dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))


@pytest.mark.parametrize(
    ("argv", "status", "message"),
    [
        (["render", "--exposure", "nan"], 2, "fovjax render: error: --exposure nan"),
        (["record", "--gaze", "serial:/dev/ttyNOPE", "--seconds", "2", "--wait", "0.5"], 1, "/dev/ttyNOPE"),
    ],
)
def test_program_exits_with_status_and_one_line(argv, status, message, tmp_path):
    argv = [*argv, "-o", str(tmp_path / ("x.jsonl" if argv[0] == "record" else "x.png"))]
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "fovjax", *argv], capture_output=True, text=True, env=_env(), timeout=120
    )
    assert proc.returncode == status, proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert not list(tmp_path.iterdir())
    assert time.monotonic() - t0 < 120


# -- Ctrl-C ----------------------------------------------------------------------------------
def _interrupt(cmd, ready, tmp_path, timeout=120.0, signum=signal.SIGINT):
    """Start `cmd`, wait until `ready()` (or its stderr says so), send `signum` (SIGINT: a
    Ctrl-C), return the result."""
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=_env())
        try:
            deadline = time.monotonic() + timeout
            while not ready(log.read_text()) and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            assert proc.poll() is None, f"finished before the interrupt: {log.read_text()}"
            proc.send_signal(signum)
            out, _ = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    return proc.returncode, out, log.read_text()


def test_ctrl_c_while_render_compiles_exits_130_without_a_crash(tmp_path):
    out = tmp_path / "img.png"
    # Five bounces (the default): a program that takes seconds to compile on any machine.
    cmd = [sys.executable, "-m", "fovjax", "render", *TINY, "--mono", "-o", str(out)]
    status, stdout, stderr = _interrupt(cmd, lambda text: "[3/4] compiling" in text, tmp_path)
    assert status == 130, stderr  # not -11 (segmentation fault) or 1
    assert "fovjax render: interrupted; nothing was written" in stderr
    assert "Traceback" not in stderr
    assert not out.exists() and not list(tmp_path.glob(".*part*"))


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_ctrl_c_during_a_session_exits_130_and_keeps_a_complete_log(tmp_path, signum):
    """Ctrl-C, or SIGTERM (`kill`'s signal, taken as a Ctrl-C): the frames so far and the log."""
    out = tmp_path / "session"
    cmd = [sys.executable, "-m", "fovjax", "session", "--gaze", "synthetic:fixed", "--frames", "100000"]
    cmd += [*TINY, "--max-depth", "1", "--no-progress", "-o", str(out)]
    # Interrupted after the first frame, while the next one (tracking now ok) compiles.
    ready = lambda text: (out / "frame_00000.png").exists()  # noqa: E731
    status, stdout, stderr = _interrupt(cmd, ready, tmp_path, signum=signum)
    assert status == 130, stderr
    assert "fovjax session: interrupted; wrote" in stderr and "Traceback" not in stderr
    log = json.loads((out / "session.json").read_text())
    assert log["summary"]["interrupted"] is True
    frames = sorted(out.glob("frame_*.png"))
    assert len(frames) == log["summary"]["frames"] == len(log["frames"]) >= 1
    assert not list(out.glob(".*part*"))  # no half-written file left behind


@pytest.fixture
def default_sigint():
    """Python's own Ctrl-C handler while the test runs (a test runner may have another)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_write_is_not_cut_by_ctrl_c(default_sigint, signum):
    from fovjax.cli import deferred_interrupt

    term = signal.getsignal(signal.SIGTERM)
    finished = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupt():
            os.kill(os.getpid(), signum)
            time.sleep(0.05)  # the signal is taken here and held
            finished.append(True)
    assert finished == [True]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    assert signal.getsignal(signal.SIGTERM) is term


def test_interrupt_flag_is_set_even_when_the_exception_is_lost(default_sigint):
    from fovjax.files import interrupt_flag

    with interrupt_flag() as stop:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        except KeyboardInterrupt:
            pass  # as if swallowed (e.g. raised inside a gc callback)
        assert stop.is_set()


def test_atomic_path_leaves_the_old_file_or_the_new_one(tmp_path):
    from fovjax.cli import atomic_path

    path = tmp_path / "a.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("stopped while writing")
    assert path.read_text() == "old" and list(tmp_path.iterdir()) == [path]
    with atomic_path(path) as tmp:
        tmp.write_text("new")
    assert path.read_text() == "new" and list(tmp_path.iterdir()) == [path]


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads /proc/PID/maps (Linux)")
def test_ctrl_c_while_the_program_starts_exits_130(tmp_path):
    """Interrupted while JAX is still being imported (its library just mapped), before `main`."""
    cmd = [sys.executable, "-m", "fovjax", "render", *TINY, "--mono", "-o", str(tmp_path / "img.png")]
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=_env())
        maps = Path(f"/proc/{proc.pid}/maps")
        try:
            deadline = time.monotonic() + 60
            while proc.poll() is None and time.monotonic() < deadline:
                try:
                    if "jaxlib" in maps.read_text():
                        break
                except OSError:
                    pass
                time.sleep(0.005)
            assert proc.poll() is None, log.read_text()
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    stderr = log.read_text()
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "nothing was written" in stderr
    assert "Traceback" not in stderr
    assert not (tmp_path / "img.png").exists()
