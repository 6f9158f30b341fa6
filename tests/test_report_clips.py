"""Novel-view clips (WebM video, GIF and the page playing the video) and the configuration page, on a tiny generated scene."""

import base64
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from recondreamer.cli import main
from recondreamer.errors import RecondreamerError
from recondreamer.report import clips
from recondreamer.report.config_page import config_page

WIDTH, HEIGHT, FRAMES = 48, 32, 4


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    path = tmp_path_factory.mktemp("clip") / "scene"
    write_scene(path, generate_segment(5, "quick", frames=FRAMES, width=WIDTH, height=HEIGHT))
    return path


def flat_frames(directory, colour_of_frame, count=FRAMES, size=(WIDTH, HEIGHT)):
    """Frames of one colour each: they survive the GIF's palette exactly."""
    directory.mkdir(parents=True, exist_ok=True)
    for t in range(count):
        Image.fromarray(np.full((size[1], size[0], 3), colour_of_frame(t), np.uint8)).save(directory / f"{t:03d}.png")
    return directory


def gif_frames(path):
    with Image.open(path) as image:
        assert image.format == "GIF" and image.info["loop"] == 0
        frames = []
        for index in range(image.n_frames):
            image.seek(index)
            frames.append((np.asarray(image.convert("RGB")), image.info["duration"]))
    return frames


def test_clip_shows_each_panel_enlarged_under_its_label_and_the_true_view(tmp_path, scene_dir):
    from recondreamer.scene import load_scene

    panels = [
        ("degraded (a)", flat_frames(tmp_path / "a", lambda t: (200, 10 * t, 0))),
        ("restored", flat_frames(tmp_path / "b", lambda t: (0, 200, 10 * t))),
        ("ReconDreamer (a)", flat_frames(tmp_path / "c", lambda t: (10 * t, 0, 200))),
    ]
    out = tmp_path / "clips" / "seg.gif"
    arguments = [arg for label, folder in panels for arg in ("--panel", f"{label}={folder}")]
    assert main(["novel-view-clip", "--scene", str(scene_dir), "--trajectory", "shift@6", *arguments, "--out", str(out), "--fps", "5", "--min-panel-width", "100"]) == 0
    frames = gif_frames(out)
    assert len(frames) == FRAMES and all(duration == 200 for _, duration in frames)
    scale = 3  # the smallest whole factor that makes 48 pixels at least 100
    panel_w, panel_h = WIDTH * scale, HEIGHT * scale
    cell_w, cell_h = panel_w + clips._GAP, clips._LABEL_HEIGHT + panel_h + clips._GAP
    assert frames[0][0].shape == (2 * cell_h - clips._GAP, 2 * cell_w - clips._GAP, 3)  # four panels, two a row
    truth = load_scene(scene_dir)
    for t, (image, _) in enumerate(frames):
        for i, (_, folder) in enumerate(panels):
            x, y = (i % 2) * cell_w, (i // 2) * cell_h + clips._LABEL_HEIGHT
            expected = np.asarray(Image.open(folder / f"{t:03d}.png").convert("RGB"))[0, 0]
            np.testing.assert_array_equal(image[y : y + panel_h, x : x + panel_w], np.broadcast_to(expected, (panel_h, panel_w, 3)))
        # The fourth panel is the true novel view, each pixel repeated scale x scale (the palette may move a colour a little).
        x, y = cell_w, cell_h + clips._LABEL_HEIGHT
        shown = image[y : y + panel_h : scale, x : x + panel_w : scale].astype(int)
        assert np.abs(shown - truth.novel_image("shift@6", t).astype(int)).mean() < 4.0
        assert image[: clips._LABEL_HEIGHT].min() < 100  # dark label text on the white strip
    # The video: the same frames (VP8 keeps flat colours within a few levels), embedded in the page.
    video = clips.decode_video(out.with_suffix(".webm"))
    assert len(video) == FRAMES and video[0].shape == frames[0][0].shape
    for (image, _), decoded in zip(frames, video):
        assert np.abs(decoded.astype(int) - image.astype(int)).mean() < 3.0
    page = out.with_suffix(".html").read_text()
    embedded = re.search(r'<video src="data:video/webm;base64,([^"]+)"[^>]* autoplay loop muted', page).group(1)
    assert base64.b64decode(embedded) == out.with_suffix(".webm").read_bytes()
    for label in ("degraded (a)", "restored", "ReconDreamer (a)", clips.TRUTH_LABEL):
        assert f"<b>{label}</b>" in page
    assert str(tmp_path / "b") in page


def test_clip_without_a_true_view_and_bad_inputs(tmp_path, scene_dir):
    folder = flat_frames(tmp_path / "a", lambda t: (50, 50, 50))
    gif, video, page = clips.novel_view_clip(scene_dir, "shift@1", [("only", folder)], tmp_path / "one.gif", min_panel_width=48)
    assert video == tmp_path / "one.webm"
    image, _ = gif_frames(gif)[0]
    assert image.shape == (clips._LABEL_HEIGHT + HEIGHT, WIDTH, 3)  # the scene has no true view along shift@1
    assert clips.TRUTH_LABEL not in page.read_text()
    short = flat_frames(tmp_path / "short", lambda t: (0, 0, 0), count=FRAMES - 1)
    with pytest.raises(RecondreamerError, match=f"{short}"):
        clips.novel_view_clip(scene_dir, "shift@6", [("short", short)], tmp_path / "x.gif")
    small = flat_frames(tmp_path / "small", lambda t: (0, 0, 0), size=(24, 16))
    with pytest.raises(RecondreamerError, match="expected 48x32"):
        clips.novel_view_clip(scene_dir, "shift@6", [("small", small)], tmp_path / "x.gif")
    with pytest.raises(RecondreamerError, match="expected LABEL=FRAME_FOLDER"):
        clips.parse_panel("no folder")
    with pytest.raises(RecondreamerError, match="expected a .gif"):
        clips.novel_view_clip(scene_dir, "shift@6", [("a", folder)], tmp_path / "x.mp4")
    with pytest.raises(RecondreamerError, match="--fps 0"):
        clips.novel_view_clip(scene_dir, "shift@6", [("a", folder)], tmp_path / "x.gif", fps=0)
    assert not (tmp_path / "x.gif").exists() and not (tmp_path / "x.webm").exists()
    assert clips.parse_panel("a = b=c/d") == ("a = b", Path("c/d"))


def test_config_page_shows_the_yaml_escaped(tmp_path):
    (tmp_path / "run_config.yaml").write_text("results_dir: results/quick\nnote: <b>&</b>\n")
    page = config_page(tmp_path / "run_config.yaml", tmp_path / "run_config.html").read_text()
    assert "<pre>results_dir: results/quick\nnote: &lt;b&gt;&amp;&lt;/b&gt;\n</pre>" in page
    assert main(["config-page", str(tmp_path / "absent.yaml"), "--out", str(tmp_path / "x.html")]) == 1
    assert not (tmp_path / "x.html").exists()
