"""``evfuse dataset DIR`` (issue 24, part 5): the summary and the dataset card, on the
``small_dataset`` fixture (conftest: two done sequences, one failed job, one pending)."""

from __future__ import annotations

import csv
import shutil

import cv2
import numpy as np
import pytest

from fusion.cli import main
from sim.dataset import CARD, dataset_summary, write_card
from sim.output import MARKER
from sim.validation import ParameterError
from tests.conftest import tree_hashes


def _manifest(folder):
    with (folder / "manifest.csv").open(newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.fixture()
def dataset_copy(small_dataset, tmp_path):
    copy = tmp_path / "tiny"
    shutil.copytree(small_dataset, copy)
    return copy


def test_the_card_names_every_sequence_and_matches_the_manifest(dataset_copy, capsys):
    before = tree_hashes(dataset_copy)
    assert main(["dataset", str(dataset_copy)]) == 0
    out = capsys.readouterr().out
    rows = _manifest(dataset_copy)
    done = [row for row in rows if row["status"] == "done"]
    events = sum(int(row["events"]) for row in done)
    frames = sum(int(row["frames"]) for row in done)
    assert f"{len(done)} sequences done, 1 failed, 1 pending" in out
    assert f"events {events:,}, frames {frames:,}, simulated 0.200 s" in out
    assert f"event rate {events / 0.2:,.0f} events/s over all" in out
    assert "failed: broken-0: ValueError: the scene cannot render" in out
    assert "manifest disagrees" not in out
    card = (dataset_copy / CARD).read_text()
    for row in done:                  # each sequence's row: its events and frames as counted
        line = next(line for line in card.splitlines() if line.startswith(f"| {row['job_id']} |"))
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        assert cells[1:5] == [row["scene"], "48x36", row["events"], row["frames"]]
        assert float(cells[5]) == float(row["duration_s"])
        assert float(cells[6]) == pytest.approx(int(row["events"]) / 0.1, rel=1e-3)
    assert "| broken-0 | ValueError: the scene cannot render |" in card
    assert "Pending jobs: later-0." in card and "![contact sheet](card/contact_sheet.png)" in card
    sheet = cv2.imread(str(dataset_copy / "card" / "contact_sheet.png"))
    assert sheet.shape[0] == 18 + 2 * (18 + 108 + 6)          # header, then a row a sequence
    assert sheet.shape[1] >= 3 * 144                           # frame, events, depth at 108 px
    after = tree_hashes(dataset_copy)
    written = {str(dataset_copy / CARD), str(dataset_copy / "card"),
               str(dataset_copy / "card" / "contact_sheet.png")}
    assert {k: v for k, v in after.items() if k not in written} == before   # nothing else
    assert not list(dataset_copy.rglob("*.partial"))


def test_the_summarys_figures_are_measured_on_the_files(small_dataset):
    """Depth range over the depth maps, speeds against the poses' finite differences."""
    from sim.exr import read_depth
    from sim.sequence import load_sequence
    from sim.trajectory import read_trajectory

    summary = dataset_summary(small_dataset)
    assert [s.job_id for s in summary.sequences] == ["complex_sphere-0", "boxes_6dof-0"]
    for row in summary.sequences:
        seq = load_sequence(small_dataset / "jobs" / row.job_id)
        depths = np.concatenate([read_depth(p).ravel() for p in seq.depth_paths])
        assert (row.depth_min, row.depth_max) == (depths[depths > 0].min(), depths.max())
        poses = read_trajectory(seq.groundtruth_path)
        times = np.linspace(0.5, 0.6, 201)
        positions = poses.pose(times)[:, :3, 3]
        speed = np.linalg.norm(np.diff(positions, axis=0), axis=1) / np.diff(times)
        assert row.speed_mean == pytest.approx(speed.mean(), rel=0.02, abs=1e-6)
        assert row.frames == 6 and row.event_rate == row.events / 0.1


def test_a_manifest_that_disagrees_is_said(dataset_copy):
    text = (dataset_copy / "manifest.csv").read_text()
    rows = _manifest(dataset_copy)
    wrong = text.replace(f",{rows[1]['events']},", f",{int(rows[1]['events']) + 1},", 1)
    assert wrong != text
    (dataset_copy / "manifest.csv").write_text(wrong)
    summary = dataset_summary(dataset_copy)
    assert summary.mismatches == (f"boxes_6dof-0: events {int(rows[1]['events']) + 1} in the "
                                  f"manifest, {rows[1]['events']} in its folder",)
    assert "manifest disagrees: boxes_6dof-0: events" in summary.text()


def test_the_card_is_written_only_into_a_folder_evfuse_wrote(dataset_copy, capsys):
    (dataset_copy / MARKER).unlink()
    before = tree_hashes(dataset_copy)
    with pytest.raises(ParameterError, match="has no .evfuse marker"):
        write_card(dataset_copy)
    assert main(["dataset", str(dataset_copy), "--no-card"]) == 0      # the summary only
    assert "2 sequences done" in capsys.readouterr().out
    assert tree_hashes(dataset_copy) == before


def test_a_folder_without_a_manifest_is_refused(tmp_path, capsys):
    assert main(["dataset", str(tmp_path)]) == 2
    assert "has no manifest.csv: not a dataset folder" in capsys.readouterr().err
