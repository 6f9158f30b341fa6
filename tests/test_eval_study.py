"""Preference study: win-rate counting, the automatic judge, the study page and CSV ingestion."""

import csv
import json

import numpy as np
import pytest
from PIL import Image

from recondreamer.cli import main
from recondreamer.errors import RecondreamerError
from recondreamer.evaluation.study import Clip, Comparison, build_study_page, judge_pair, read_study_csvs, win_rates


def _frames(directory, frames):
    directory.mkdir(parents=True, exist_ok=True)
    for t, frame in enumerate(frames):
        Image.fromarray(frame).save(directory / f"{t:03d}.png")
    return directory


def test_win_rates_per_trajectory_with_ties_and_average():
    comparisons = [
        Comparison("shift@3", "ours", "base", "ours"),
        Comparison("shift@3", "base", "ours", "ours"),
        Comparison("shift@3", "ours", "base", "base"),
        Comparison("shift@6", "ours", "base", "ours"),
        Comparison("shift@6", "ours", "base", None),
    ]
    result = {(p["method"], p["versus"]): p for p in win_rates(comparisons)["pairs"]}
    ours = result[("ours", "base")]
    assert ours["per_trajectory"]["shift@3"]["win_rate"] == pytest.approx(2 / 3)
    assert ours["per_trajectory"]["shift@6"]["win_rate"] == pytest.approx(0.75)  # a tie counts half
    assert ours["average"] == pytest.approx((2 / 3 + 0.75) / 2)
    assert result[("base", "ours")]["per_trajectory"]["shift@3"]["win_rate"] == pytest.approx(1 / 3)


def test_judge_prefers_the_render_closer_to_the_truth():
    rng = np.random.default_rng(0)
    truth = rng.integers(0, 256, size=(4, 24, 32, 3)).astype(np.uint8)
    slightly = np.clip(truth + rng.normal(0, 5, truth.shape), 0, 255).astype(np.uint8)
    badly = np.clip(truth + rng.normal(0, 40, truth.shape), 0, 255).astype(np.uint8)
    for metric in ("ssim", "psnr"):
        assert judge_pair(truth, slightly, badly, metric)[0] == "a"
        assert judge_pair(truth, badly, slightly, metric)[0] == "b"
    assert judge_pair(truth, slightly, slightly)[0] == "tie"


def test_study_page_placement_csv_and_ingest(tmp_path):
    rng = np.random.default_rng(1)
    dirs = {name: _frames(tmp_path / name, rng.integers(0, 256, size=(3, 16, 24, 3)).astype(np.uint8)) for name in ("ours", "base")}
    clips = [Clip(f"scene{i}", trajectory, (("ours", dirs["ours"]), ("base", dirs["base"]))) for i in range(3) for trajectory in ("shift@3", "shift@6")]
    page = tmp_path / "page"
    placement = build_study_page(clips, page, seed=4)
    html = (page / "index.html").read_text()
    assert "http://" not in html and "https://" not in html  # offline: no CDN
    assert "ours" not in html and "base" not in html  # the page does not reveal the methods
    tops = {c["top"] for c in placement["clips"]}
    assert tops == {"ours", "base"}  # both placements occur with this seed
    for entry in placement["clips"]:
        for slot in ("top", "bottom"):
            with Image.open(page / "media" / f"{entry['clip_id']}_{slot}.webp") as animation:
                assert animation.n_frames == 3
    # A participant who always picks "ours", wherever it is placed.
    answers = tmp_path / "answers.csv"
    with open(answers, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["participant", "clip_id", "choice", "time"])
        for entry in placement["clips"]:
            writer.writerow(["p1", entry["clip_id"], "top" if entry["top"] == "ours" else "bottom", ""])
    out = tmp_path / "winrates.json"
    assert main(["study-ingest", str(answers), "--placement", str(page / "placement.json"), "--out", str(out)]) == 0
    pairs = {(p["method"], p["versus"]): p for p in json.loads(out.read_text())["pairs"]}
    assert pairs[("ours", "base")]["average"] == 1.0
    assert pairs[("ours", "base")]["per_trajectory"]["shift@6"]["comparisons"] == 3


def test_study_ingest_rejects_bad_csv(tmp_path):
    placement = tmp_path / "placement.json"
    placement.write_text(json.dumps({"seed": 0, "clips": [{"clip_id": "clip000", "scene": "s", "trajectory": "shift@3", "top": "a", "bottom": "b"}]}))
    bad = tmp_path / "bad.csv"
    bad.write_text("participant,clip_id,choice,time\np,clip000,left,\n")
    with pytest.raises(RecondreamerError, match=r"bad.csv:2: choice 'left'"):
        read_study_csvs([bad], placement)
    unknown = tmp_path / "unknown.csv"
    unknown.write_text("participant,clip_id,choice,time\np,clip999,top,\n")
    with pytest.raises(RecondreamerError, match="clip999"):
        read_study_csvs([unknown], placement)


class TestDamagedStudyCsv:
    """A file that is not (all of) the study page's download is one error naming it and the line."""

    @pytest.fixture
    def placement(self, tmp_path):
        path = tmp_path / "placement.json"
        path.write_text(json.dumps({"seed": 0, "clips": [{"clip_id": "clip000", "scene": "s", "trajectory": "shift@3", "top": "a", "bottom": "b"}]}))
        return path

    def test_binary_bytes(self, tmp_path, placement):
        bad = tmp_path / "bad.csv"
        bad.write_bytes(bytes(range(128, 256)) * 20)  # not UTF-8
        with pytest.raises(RecondreamerError, match=r"bad.csv: not a study CSV file"):
            read_study_csvs([bad], placement)

    def test_a_row_cut_short(self, tmp_path, placement):
        cut = tmp_path / "cut.csv"
        cut.write_text("participant,clip_id,choice,time\np1,clip000,top,3.1\np2,clip000")  # the download stopped mid-row
        with pytest.raises(RecondreamerError, match=r"cut.csv:3: row cut short \(2 of 4 fields"):
            read_study_csvs([cut], placement)

    def test_study_ingest_prints_one_line_and_writes_nothing(self, tmp_path, placement, capsys):
        bad = tmp_path / "bad.csv"
        bad.write_bytes(bytes(range(128, 256)) * 20)
        out = tmp_path / "win_rates.json"
        assert main(["study-ingest", "--placement", str(placement), "--out", str(out), str(bad)]) == 1
        err = capsys.readouterr().err
        assert err.count("error:") == 1 and "bad.csv: not a study CSV file" in err and "Traceback" not in err
        assert not out.exists()
