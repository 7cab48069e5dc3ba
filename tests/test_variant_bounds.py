"""Figures whose bound depends on the Mitsuba variant (issue 36): each variant's own bound where
it has one; where it has none yet, the bound measured on llvm_ad_rgb, and the figure recorded
(a warning, and a line in ``EVFUSE_VARIANT_FIGURES``'s file) rather than skipped."""

from __future__ import annotations

import json

import pytest

from tests.conftest import VARIANT_FIGURES_ENV, bound_for


def test_a_variant_with_its_own_bound_is_checked_against_it(tmp_path, monkeypatch, recwarn):
    monkeypatch.setenv(VARIANT_FIGURES_ENV, str(tmp_path / "figures.jsonl"))
    bounds = {"llvm_ad_rgb": 0.15, "cuda_ad_rgb": 0.12}
    assert bound_for("cuda_ad_rgb", "gain", 0.13, bounds) == 0.12
    assert bound_for("llvm_ad_rgb", "gain", 0.13, bounds) == 0.15
    assert not (tmp_path / "figures.jsonl").exists() and not recwarn.list


def test_a_variant_without_a_bound_gets_llvms_and_its_figure_is_recorded(tmp_path,
                                                                          monkeypatch):
    monkeypatch.setenv(VARIANT_FIGURES_ENV, str(tmp_path / "figures.jsonl"))
    with pytest.warns(UserWarning, match="gain = 0.17 on cuda_ad_rgb, which has no bound"):
        assert bound_for("cuda_ad_rgb", "gain", 0.17, {"llvm_ad_rgb": 0.15}, "t::x") == 0.15
    with pytest.warns(UserWarning):
        bound_for("cuda_ad_rgb", "ratio", 1.4, {"llvm_ad_rgb": 1.3}, "t::y")
    lines = [json.loads(line) for line in (tmp_path / "figures.jsonl").read_text().splitlines()]
    assert lines == [
        {"test": "t::x", "figure": "gain", "variant": "cuda_ad_rgb", "value": 0.17,
         "bound_from": "llvm_ad_rgb", "bound": 0.15},
        {"test": "t::y", "figure": "ratio", "variant": "cuda_ad_rgb", "value": 1.4,
         "bound_from": "llvm_ad_rgb", "bound": 1.3}]


def test_the_fixture_knows_the_suites_variant(variant, variant_bound):
    assert variant in ("llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb")
    assert variant_bound("x", 1.0, {"llvm_ad_rgb": 2.0, variant: 3.0}) == 3.0
