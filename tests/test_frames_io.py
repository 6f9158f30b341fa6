"""recondreamer.frames_io: the one reader and writer of frame folders."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from recondreamer.errors import RecondreamerError
from recondreamer.frames_io import FrameError, frame_files, read_clip, read_frame_folder, write_frames


def clip(frames: int = 3, height: int = 8, width: int = 12) -> np.ndarray:
    return np.random.default_rng(frames).integers(0, 256, size=(frames, height, width, 3), dtype=np.uint8)


class TestRoundTrip:
    def test_write_then_read(self, tmp_path):
        frames = clip()
        write_frames(tmp_path / "clip", frames, {"scene_id": "x"})
        assert np.array_equal(read_frame_folder(tmp_path / "clip"), frames)
        assert np.array_equal(read_frame_folder(tmp_path / "clip", 3, (12, 8)), frames)
        assert (tmp_path / "clip" / "info.json").is_file()

    def test_read_clip_takes_an_npy_or_the_trajectory_sub_folder(self, tmp_path):
        frames = clip()
        np.save(tmp_path / "clip.npy", frames)
        assert np.array_equal(read_clip(tmp_path / "clip.npy"), frames)
        write_frames(tmp_path / "renders" / "shift@3", frames)
        assert np.array_equal(read_clip(tmp_path / "renders", "shift@3"), frames)


class TestErrors:
    def test_missing_extra_and_duplicate_frames_are_named(self, tmp_path):
        write_frames(tmp_path / "clip", clip(4))
        with pytest.raises(FrameError, match=r"lacks 1 of 5 frames: .*004.png"):
            frame_files(tmp_path / "clip", 5)
        with pytest.raises(FrameError, match=r"003.png: frame 3 is beyond the scene's 3 frames"):
            frame_files(tmp_path / "clip", 3)
        (tmp_path / "clip" / "001.png").rename(tmp_path / "clip" / "1.png")
        Image.fromarray(clip(1)[0]).save(tmp_path / "clip" / "001.jpg")
        with pytest.raises(FrameError, match="frame 1 is given twice"):
            frame_files(tmp_path / "clip")

    def test_a_gap_sizes_and_unreadable_files(self, tmp_path):
        write_frames(tmp_path / "clip", clip(3))
        (tmp_path / "clip" / "001.png").unlink()
        with pytest.raises(FrameError, match=r"lacks 1 of 3 frames: .*001.png"):
            read_frame_folder(tmp_path / "clip")
        Image.fromarray(clip(1, height=9)[0]).save(tmp_path / "clip" / "001.png")
        with pytest.raises(FrameError, match=r"001.png: frame is 12x9, expected 12x8"):
            read_frame_folder(tmp_path / "clip")
        (tmp_path / "clip" / "001.png").write_text("not an image")
        with pytest.raises(FrameError, match="001.png: not a readable image"):
            read_frame_folder(tmp_path / "clip")
        with pytest.raises(FrameError, match="does not exist"):
            read_frame_folder(tmp_path / "absent")
        (tmp_path / "empty").mkdir()
        with pytest.raises(FrameError, match="holds no numbered frames"):
            read_frame_folder(tmp_path / "empty")

    def test_bad_npy(self, tmp_path):
        np.save(tmp_path / "bad.npy", np.zeros((2, 4, 4), np.float32))
        with pytest.raises(RecondreamerError, match=r"bad.npy: expected a \(T,H,W,3\) uint8 array"):
            read_clip(tmp_path / "bad.npy")

    def test_damaged_npy(self, tmp_path):
        (tmp_path / "noise.npy").write_bytes(np.random.default_rng(0).bytes(3000))
        with pytest.raises(RecondreamerError, match=r"noise.npy: not a readable .npy clip"):
            read_clip(tmp_path / "noise.npy")
        np.save(tmp_path / "whole.npy", clip())
        data = (tmp_path / "whole.npy").read_bytes()
        (tmp_path / "cut.npy").write_bytes(data[: len(data) // 2])
        with pytest.raises(RecondreamerError, match=r"cut.npy: not a readable .npy clip"):
            read_clip(tmp_path / "cut.npy")
