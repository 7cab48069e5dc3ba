"""Adaptive sampling of the renderer for the event camera: the bound, refinement, convergence."""

from __future__ import annotations

import numpy as np
import pytest

from sim.camera import Camera
from sim.events import EventEmulator, EventParams
from sim.render import Renderer
from sim.sampling import (
    AT_MAX_RATE_WARN_SHARE,
    SPLIT,
    Sample,
    SamplingParams,
    SamplingStats,
    adaptive_samples,
    contrast_scale,
    max_rate_warning,
    motion_field,
)
from sim.scene import parse_scene
from sim.se3 import so3_exp
from tests.conftest import scene_text

CHECKER = """
[[objects]]
name = "checker"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [4.0, 4.0]
material = { texture = { type = "checkerboard", squares = [8, 8], color0 = 0.05, color1 = 0.85 } }
"""
SLIDE = ('[trajectory]\ntype = "linear"\nposition = [0.03, 0.0, 0.01]\n'
         "velocity = [0.5, 0.0, 0.1]\nlook_at = [0.03, 1.0, 0.01]\n")
C = 0.2


@pytest.fixture(scope="module")
def edge_renderer():
    return Renderer(parse_scene(scene_text(CHECKER, trajectory=SLIDE)), spp=4)


def _run(renderer, lam, t1=0.1, max_rate=20000.0):
    params = EventParams()
    emulator = EventEmulator((renderer.camera.height, renderer.camera.width), params)
    stats = SamplingStats()
    samples, chunks = [], []
    for sample in adaptive_samples(renderer, 0.0, t1, C, params.log_eps,
                                   SamplingParams(lam=lam, max_rate=max_rate), stats):
        if not samples:
            emulator.start(sample.log, sample.t)
        else:
            chunks.append(emulator.advance(sample.log, sample.t))
        samples.append(sample)
    return samples, np.concatenate(chunks), stats


def _check_bound_or_step_rule(samples, bound, max_rate):
    """Every interval either keeps each pixel's |delta L| <= bound, or is at the minimum step
    (could not be halved: shorter than 2 / max_rate), or is one half of an interval [a, b]
    whose midpoint m split none of its violating changes (the sub-pixel-step rule: each such
    pixel changed by <= SPLIT or >= 1 - SPLIT of its change over [a, b] by m). Checked on the
    samples' own log images, not on their flags. Returns (met, at the minimum step, steps)."""
    counts = [0, 0, 0]
    for k in range(1, len(samples)):
        prev, sample = samples[k - 1], samples[k]
        change = np.abs(sample.log - prev.log).max()
        assert sample.max_change == pytest.approx(change, abs=1e-12)
        assert sample.bound_met == (change <= bound)
        if change <= bound:
            counts[0] += 1
        elif sample.tail_pending or prev.tail_pending:       # one half of a kept pair
            a, m, b = ((prev, sample, samples[k + 1]) if sample.tail_pending
                       else (samples[k - 2], prev, sample))
            assert m.t == pytest.approx((a.t + b.t) / 2, abs=1e-12)
            full = np.abs(b.log - a.log)
            violating = full > bound
            share = np.abs(m.log - a.log)[violating] / full[violating]
            assert violating.any() and not np.any((share > SPLIT) & (share < 1 - SPLIT))
            counts[2] += 1
        else:
            assert sample.t - prev.t < 2 / max_rate, (sample.t, change)
            counts[1] += 1
    return tuple(counts)


def test_motion_field_matches_projected_point_motion():
    camera = Camera(64, 48, 60.0, 45.0, 30.3, 22.7)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 3.0, (48, 64))
    v, w = np.array([0.3, -0.1, 0.2]), np.array([0.2, 0.5, -0.3])
    du, dv = motion_field(camera, depth, v, w)
    xy = camera.normalized_pixel_centres()
    points = np.concatenate([xy, np.ones_like(xy[..., :1])], -1) * depth[..., None]
    h = 1e-6                                          # move the camera by h seconds of the twist
    R = so3_exp(w * h)
    moved = (points - v * h) @ R                      # camera-frame coordinates after the motion
    uv = camera.project(moved.reshape(-1, 3)).reshape(48, 64, 2)
    np.testing.assert_allclose(du, (uv[..., 0] - camera.pixel_centres()[..., 0]) / h, rtol=1e-4,
                               atol=1e-3)
    np.testing.assert_allclose(dv, (uv[..., 1] - camera.pixel_centres()[..., 1]) / h, rtol=1e-4,
                               atol=1e-3)


def test_every_interval_keeps_the_bound_or_breaks_it_by_sub_pixel_steps(edge_renderer):
    """On a sharp checker at 4 spp every interval keeps the bound or is accounted for by the step
    rule (an edge crossing a sub-pixel sample: a step that no shorter interval shrinks), checked
    on the logs; intervals at the minimum step are the rare exception. The texture is filtered
    over each sub-sample's footprint, so its edges rarely make steps (2 of 355 intervals on
    llvm_ad_rgb, none on cuda_ad_rgb): the geometric edges below do."""
    lam = 0.5
    samples, events, stats = _run(edge_renderer, lam)
    assert len(events) > 100 and stats.renders >= len(samples) > 20
    met, at_min, steps = _check_bound_or_step_rule(samples, lam * C, 20000.0)
    assert met + at_min + steps == len(samples) - 1
    assert steps <= 2 * stats.steps                          # each kept pair: two halves
    assert at_min <= 1 and stats.at_max_rate <= 1
    assert samples[-1].t == pytest.approx(0.1)


def test_a_geometric_edge_makes_steps_that_the_rule_accounts_for():
    """A thin bar in front of the checker: its silhouette crosses the sub-pixel samples as a step
    (geometry is not filtered), which halving cannot shrink; every such interval is one half of a
    kept pair whose midpoint split none of its changes."""
    bar = CHECKER + """
[[objects]]
name = "bar"
type = "box"
center = [0.0, 0.6, 0.0]
size = [0.05, 0.02, 0.5]
material = { color = 0.9 }
"""
    renderer = Renderer(parse_scene(scene_text(bar, trajectory=SLIDE)), spp=4)
    samples, events, stats = _run(renderer, 0.5, t1=0.01)
    met, at_min, steps = _check_bound_or_step_rule(samples, 0.5 * C, 20000.0)
    assert met + at_min + steps == len(samples) - 1
    assert 0 < steps <= 2 * stats.steps and at_min <= 1


def test_motion_the_prediction_cannot_see_is_caught_and_refined():
    # A static camera (predicted flow 0: the 100 Hz minimum rate) and a moving textured box.
    objects = CHECKER + """
[[objects]]
name = "mover"
type = "box"
center = [0.0, 0.7, 0.0]
size = [0.15, 0.15, 0.15]
material = { texture = { type = "noise", resolution = 64, feature_size = 3.0 } }
motion = { type = "linear", velocity = [0.5, 0.0, 0.0] }
"""
    renderer = Renderer(parse_scene(scene_text(objects)), spp=4)
    samples, _, stats = _run(renderer, 0.5, t1=0.05)
    steps = np.diff([s.t for s in samples])
    assert stats.refined > 0 and steps.min() < 0.5 * (1 / 100)
    _check_bound_or_step_rule(samples, 0.5 * C, 20000.0)


def test_halving_lambda_barely_changes_the_events(edge_renderer):
    """Halving lambda changes the count by < 1 % and moves events by < one sampling interval.

    Matched pixel by pixel, in order. A handful of events (< 0.5 %) belong to pixels whose level
    sits within ~1e-3 of a threshold in a nearly flat region: their timing is decided by tiny
    wiggles and is ill-conditioned in any emulator; they are allowed to move further.
    """
    coarse_samples, coarse, _ = _run(edge_renderer, 0.5)
    _, fine, _ = _run(edge_renderer, 0.25)
    assert len(coarse) > 1000
    assert abs(len(fine) - len(coarse)) < 0.01 * len(coarse)

    def by_pixel(ev):
        return ev[np.lexsort((ev["t"], ev["x"], ev["y"]))]

    a, b = by_pixel(coarse), by_pixel(fine)
    key_a = a["y"].astype(np.int64) * 1000 + a["x"]
    key_b = b["y"].astype(np.int64) * 1000 + b["x"]
    pixels, count_a = np.unique(key_a, return_counts=True)
    count_b = dict(zip(*np.unique(key_b, return_counts=True), strict=True))
    same = [p for p, n in zip(pixels, count_a, strict=True) if count_b.get(p) == n]
    assert len(same) > 0.95 * len(pixels)
    mask_a, mask_b = np.isin(key_a, same), np.isin(key_b, same)
    assert np.all(a["p"][mask_a] == b["p"][mask_b])
    ta, tb = a["t"][mask_a], b["t"][mask_b]
    times = np.array([s.t for s in coarse_samples])
    k = np.clip(np.searchsorted(times, ta / 1e9) - 1, 0, len(times) - 2)
    interval = (times[k + 1] - times[k]) * 1e9               # the coarse sampling interval
    within = np.abs(ta - tb) <= interval + 1000
    assert within.mean() > 0.995


def test_static_scene_gives_no_events_under_the_ideal_preset():
    scene = parse_scene(scene_text(CHECKER.replace("checkerboard", "noise").replace(
        ", squares = [8, 8], color0 = 0.05, color1 = 0.85", "")))
    renderer = Renderer(scene, spp=4)
    samples, events, stats = _run(renderer, 0.5, t1=0.05)
    assert stats.renders == len(samples) >= 5                  # 100 Hz minimum rate
    assert len(events) == 0


# --------------------------------------------------------------------------- max-rate warning

def test_max_rate_warning_words_the_share_and_the_cause():
    """The issue's case: a point light on a textured sphere, 4,066 of 4,131 intervals."""
    line = max_rate_warning(4066, 4131, 20000.0, 0.1)
    assert line.startswith("4,066 of 4,131 intervals (98 %) still changed log intensity by "
                           "more than lambda*C = 0.1 at the maximum rate 20 kHz: ")
    assert "point light / specular highlight or texture too fine" in line
    assert "raise --max-rate" in line and "\n" not in line
    assert max_rate_warning(0, 173, 20000.0, 0.1) is None              # the wall alone
    assert "at the maximum rate 500 Hz" in max_rate_warning(50, 60, 500.0, 0.1)


def test_max_rate_warning_threshold():
    """Above AT_MAX_RATE_WARN_SHARE (1 %) of the intervals, not at it."""
    assert AT_MAX_RATE_WARN_SHARE == 0.01
    assert max_rate_warning(1, 100, 20000.0, 0.1) is None
    assert max_rate_warning(2, 100, 20000.0, 0.1) is not None
    assert max_rate_warning(0, 0, 20000.0, 0.1) is None
    with pytest.raises(ValueError, match="0 <= at_max_rate <= intervals"):
        max_rate_warning(5, 4, 20000.0, 0.1)


def test_simulate_says_once_when_the_maximum_rate_cannot_hold_the_bound(tmp_path, capsys):
    """A checker sliding past at 100-200 Hz (the maximum rate too low for its edges): nearly
    every interval breaks the bound at the maximum rate; simulate prints one warning line and
    sequence.json explains the field."""
    import json

    from sim.simulate import simulate

    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"
    scene = parse_scene(scene_text(CHECKER, trajectory=SLIDE, duration=0.06, extra=extra))
    simulate(scene, tmp_path / "seq", progress=False, event_formats=("h5",), sampler="frame",
             sampling=SamplingParams(min_rate=100.0, max_rate=200.0))
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "maximum rate" in line]
    assert len(lines) == 1 and "at the maximum rate 200 Hz" in lines[0], err
    info = json.loads((tmp_path / "seq" / "sequence.json").read_text())["events"]
    intervals = info["samples"] - 1
    assert info["intervals_at_max_rate"] > AT_MAX_RATE_WARN_SHARE * intervals > 0
    assert f"{info['intervals_at_max_rate']:,} of {intervals:,} intervals" in lines[0]
    assert info["sampling_warning"] in lines[0]
    assert "lam * C" in info["intervals_at_max_rate_note"]


def test_contrast_scale_holds_each_pixel_to_its_own_threshold():
    assert contrast_scale(0.2) == (0.2, None)
    assert contrast_scale(np.full((2, 3), 0.2)) == (0.2, None)    # equal: the scalar path
    thresholds = np.array([[0.2, 0.11], [0.29, 0.2]])
    smallest, scale = contrast_scale(thresholds)
    assert smallest == 0.11
    np.testing.assert_allclose(scale, 0.11 / thresholds)
    # A change d meets lam C_p exactly when d * scale meets lam * C_min.
    lam, change = 0.5, np.array([[0.09, 0.06], [0.14, 0.11]])
    np.testing.assert_array_equal(change * scale <= lam * smallest, change <= lam * thresholds)
    with pytest.raises(ValueError, match=r"contrast must be a finite threshold > 0"):
        contrast_scale(np.array([[0.2, 0.0]]))


def test_the_frame_sampler_holds_a_low_threshold_pixel_to_its_own_bound(edge_renderer):
    """Columns of pixels at C = 0.11 (3 sigma low for sigma 0.03): a sample meets the bound
    exactly when those pixels changed by at most lam * 0.11 and the others by lam * 0.2 (the
    checker's sub-pixel steps leave many at the step rule); it samples more often than at the
    nominal C."""
    cam = edge_renderer.camera
    thresholds = np.full((cam.height, cam.width), C)
    thresholds[:, ::7] = 0.11
    samples = list(adaptive_samples(edge_renderer, 0.0, 0.02, thresholds, 1e-3,
                                    SamplingParams(lam=0.5)))
    for prev, sample in zip(samples[:-1], samples[1:], strict=True):
        change = np.abs(sample.log - prev.log)
        assert sample.bound_met == bool(np.all(change <= 0.5 * thresholds))
    assert any(s.bound_met for s in samples[1:])
    nominal = list(adaptive_samples(edge_renderer, 0.0, 0.02, C, 1e-3, SamplingParams(lam=0.5)))
    assert len(samples) > len(nominal)


def test_a_checkpointed_sample_keeps_the_key_refined_for_its_subdivided_flag():
    """The per-sample flag is ``subdivided`` in Python (``SamplingStats.refined`` is the count of
    midpoint renders); a checkpoint still stores the flag under ``refined``, so that checkpoint
    files are unchanged, and reads it back from there."""
    luminance, log = np.ones((2, 3), np.float32), np.zeros((2, 3))
    sample = Sample(0.25, luminance, log, 0.125, False, subdivided=True)
    assert sample.state() == {"t": 0.25, "max_change": 0.125, "bound_met": False,
                              "refined": True}
    again = Sample.from_state({"t": 0.5, "max_change": 0.0, "bound_met": True, "refined": False},
                              luminance, log)
    assert (again.t, again.max_change, again.bound_met, again.subdivided) == (0.5, 0.0, True,
                                                                              False)
    assert again.luminance is luminance and again.log is log and not again.tail_pending
