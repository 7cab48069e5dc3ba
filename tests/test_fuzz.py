"""Fuzzing (issue 21): every parser and entry point a user feeds, property-tested with Hypothesis.

The targets and their property live in :mod:`tests.fuzz_targets`: success with finite figures,
or a refusal in one line naming the input (ValueError, or exit 2), never another exception and
never a change to the input. The ``ci`` profile (tests/conftest.py) tries 200 cases per target,
the same ones on every run; ``benchmarks/fuzz.py`` runs them for thousands.
"""

from __future__ import annotations

from hypothesis import given, settings

from tests.fuzz_targets import (
    BENCH_CASES,
    CALIB_CASES,
    CONVERT_CASES,
    EVENTS_TXT_CASES,
    EXR_CASES,
    FLAG_CASES,
    GENERATE_CASES,
    GROUNDTRUTH_CASES,
    H5_CASES,
    IMAGES_CASES,
    PARAM_CASES,
    SCENE_CASES,
    SEQUENCE_JSON_CASES,
    SIMULATE_CASES,
    SWEEP_CASES,
    SWEEP_FILE_CASES,
    TWIN_CASES,
    check_bench,
    check_calib,
    check_convert,
    check_depth_exr,
    check_events_h5,
    check_events_txt,
    check_flag,
    check_generate,
    check_groundtruth,
    check_images,
    check_params,
    check_scene,
    check_sequence_json,
    check_simulate_flags,
    check_sweep,
    check_sweep_file,
    check_twin,
)

GENERATE_EXAMPLES = 100
"""Cases of generate's target: an accepted one runs a job and writes a dataset (30 cases took
1.7 s with today's refusals; an accepted case costs more)."""


@given(SCENE_CASES)
def test_fuzz_scene_toml(text):
    check_scene(text)


@given(CALIB_CASES)
def test_fuzz_calib_txt(data):
    check_calib(data)


@given(GROUNDTRUTH_CASES)
def test_fuzz_groundtruth_txt(data):
    check_groundtruth(data)


@given(IMAGES_CASES)
def test_fuzz_images_txt(data):
    check_images(data)


@given(EVENTS_TXT_CASES)
def test_fuzz_events_txt(data):
    check_events_txt(data)


@given(H5_CASES)
def test_fuzz_events_h5(edits):
    check_events_h5(edits)


@given(PARAM_CASES)
def test_fuzz_method_params(case):
    check_params(case)


@given(SWEEP_CASES)
def test_fuzz_sweep_params(case):
    check_sweep(case)


@given(FLAG_CASES)
def test_fuzz_numeric_flags(case):
    check_flag(case)


# --- targets added by issue 39: every parser and command a user feeds, up to the work ----------

@given(SWEEP_FILE_CASES)
def test_fuzz_sweep_files(text):
    check_sweep_file(text)


@given(SEQUENCE_JSON_CASES)
def test_fuzz_sequence_json(data):
    check_sequence_json(data)


@given(EXR_CASES)
def test_fuzz_depth_exr(case):
    check_depth_exr(case)


@given(CONVERT_CASES)
def test_fuzz_convert(case):
    check_convert(case)


@given(TWIN_CASES)
def test_fuzz_twin_flags(pairs):
    check_twin(pairs)


@given(BENCH_CASES)
def test_fuzz_bench_flags(pairs):
    check_bench(pairs)


# The targets that run a simulation per accepted case (a tenth of a second each): simulate's at
# the ci profile's 200 cases (4.6 s), generate's at fewer; benchmarks/fuzz.py runs them for
# --reaching-examples.
@given(SIMULATE_CASES)
def test_fuzz_simulate_flags_reach_the_simulation(pairs):
    check_simulate_flags(pairs)


@settings(max_examples=GENERATE_EXAMPLES)
@given(GENERATE_CASES)
def test_fuzz_generate_flags_and_sweeps_reach_the_jobs(case):
    check_generate(case)
