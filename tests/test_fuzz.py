"""Fuzzing (issue 21): every parser and entry point a user feeds, property-tested with Hypothesis.

The targets and their property live in :mod:`tests.fuzz_targets`: success with finite figures,
or a refusal in one line naming the input (ValueError, or exit 2), never another exception and
never a change to the input. The ``ci`` profile (tests/conftest.py) tries 200 cases per target,
the same ones on every run; ``benchmarks/fuzz.py`` runs them for thousands.
"""

from __future__ import annotations

from hypothesis import given

from tests.fuzz_targets import (
    CALIB_CASES,
    EVENTS_TXT_CASES,
    FLAG_CASES,
    GROUNDTRUTH_CASES,
    H5_CASES,
    IMAGES_CASES,
    PARAM_CASES,
    SCENE_CASES,
    SWEEP_CASES,
    check_calib,
    check_events_h5,
    check_events_txt,
    check_flag,
    check_groundtruth,
    check_images,
    check_params,
    check_scene,
    check_sweep,
)


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
