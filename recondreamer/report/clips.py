"""Novel-view clips for the report: one segment seen along a novel trajectory, several renders side
by side (the degraded baseline render, DriveRestorer's restoration of it, ReconDreamer's render)
and the true novel view when the scene has one (two panels a row), as a WebM video, an animated
GIF beside it (for slides and pages that take images only) and an HTML page playing the video.

The Snakemake report shows PNG/JPEG/SVG images and HTML pages (in a frame) and offers every other
file, videos included, only as a download. The page therefore embeds the video as a data URI: the
report is one self-contained file, in which a relative link would not resolve. WebM with VP8,
written by OpenCV's VideoWriter (its FFmpeg has no H.264 encoder), plays in every current browser,
with controls (pause, seek, full screen) the GIF lacks. Against the GIF on a quick four-panel clip
(benchmarks/opencv_images.py): 340 KB instead of 379 KB, at 35.8 dB PSNR instead of 39.7 (the
codec's half-resolution colour planes soften the enlarged pixels' colour edges), written in about
0.9 s instead of 0.1 s; VP9 halves the bytes again at 35.2 dB and three times VP8's time.
"""

from __future__ import annotations

import base64
import html
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from recondreamer.errors import RecondreamerError
from recondreamer.frames_io import read_frame_folder
from recondreamer.io import atomic_path, write_bytes_atomic, write_text_atomic

TRUTH_LABEL = "true novel view"
_LABEL_HEIGHT = 18  # pixels of the caption strip above each panel
_GAP = 4  # pixels between panels
_FONT_SIZE = 12


def parse_panel(text: str) -> tuple[str, Path]:
    """'LABEL=DIR' -> (LABEL, DIR); the label may hold spaces and '=' is split at its last occurrence."""
    label, sep, directory = text.rpartition("=")
    if not sep or not label.strip() or not directory:
        raise RecondreamerError(f"panel {text!r}: expected LABEL=FRAME_FOLDER")
    return label.strip(), Path(directory)


def clip_panels(scene_dir: str | Path, trajectory: str, panels: Sequence[tuple[str, Path]]) -> list[tuple[str, np.ndarray]]:
    """Each panel's frames (T,H,W,3), the scene's true novel view along ``trajectory`` appended when
    the scene has one; every folder must hold the scene's T frames at its size."""
    from recondreamer.scene import load_scene

    if not panels:
        raise RecondreamerError("a novel-view clip needs at least one panel (LABEL=FRAME_FOLDER)")
    scene = load_scene(scene_dir)
    size = (scene.width, scene.height)
    clips = [(label, read_frame_folder(directory, scene.num_frames, size)) for label, directory in panels]
    if trajectory in scene.novel_trajectories:
        clips.append((TRUTH_LABEL, np.stack([scene.novel_image(trajectory, t) for t in range(scene.num_frames)])))
    return clips


def compose_frames(clips: Sequence[tuple[str, np.ndarray]], min_panel_width: int = 240) -> list[Image.Image]:
    """One image per frame: the panels in rows of two (a row of four would be shrunk to illegible
    labels in the report's content pane), each under its label, enlarged by a whole factor (nearest
    neighbour, so that no detail is invented) until it is ``min_panel_width`` wide."""
    frames, height, width = clips[0][1].shape[:3]
    scale = max(1, math.ceil(min_panel_width / width))
    panel_w, panel_h = width * scale, height * scale
    columns = min(2, len(clips))
    rows = math.ceil(len(clips) / columns)
    cell_w, cell_h = panel_w + _GAP, _LABEL_HEIGHT + panel_h + _GAP
    font = ImageFont.load_default(size=_FONT_SIZE)
    background = Image.new("RGB", (columns * cell_w - _GAP, rows * cell_h - _GAP), "white")
    draw = ImageDraw.Draw(background)
    for i, (label, _) in enumerate(clips):
        x, y = (i % columns) * cell_w, (i // columns) * cell_h
        draw.text((x + 2, y + 2), _fit(draw, label, font, panel_w - 4), fill="black", font=font)
    images = []
    for t in range(frames):
        canvas = background.copy()
        for i, (_, clip) in enumerate(clips):
            panel = Image.fromarray(clip[t]).resize((panel_w, panel_h), Image.Resampling.NEAREST)
            canvas.paste(panel, ((i % columns) * cell_w, (i // columns) * cell_h + _LABEL_HEIGHT))
        images.append(canvas)
    return images


def _fit(draw: ImageDraw.ImageDraw, text: str, font, width: int) -> str:
    """``text`` cut (with an ellipsis) to fit ``width`` pixels: a long label must not run into the next panel."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "...", font=font) > width:
        text = text[:-1]
    return text + "..."


def _check_fps(fps: float) -> None:
    if fps <= 0:
        raise RecondreamerError(f"--fps {fps}: must be positive")


def write_gif(images: Sequence[Image.Image], out: Path, fps: float) -> Path:
    """An endlessly looping GIF, each frame with its own 256-colour palette."""
    _check_fps(fps)
    # Octree palettes without dithering: 40 % smaller than Pillow's default conversion on the quick
    # clips (dither noise defeats GIF's LZW compression), with faint banding on smooth skies only.
    frames = [image.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE) for image in images]
    with atomic_path(out) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=int(round(1000.0 / fps)), loop=0)
    return out


def encode_webm(frames: Sequence[np.ndarray], out: Path, fps: float, codec: str = "VP80") -> Path:
    """A WebM video (``codec`` VP80 or VP90) of (H,W,3) uint8 RGB frames; odd sizes are padded with
    a white column or row (the codecs' 4:2:0 colour planes need even sizes)."""
    _check_fps(fps)
    height, width = frames[0].shape[:2]
    even = (width + width % 2, height + height % 2)
    with tempfile.TemporaryDirectory() as tmp:
        file = Path(tmp) / "clip.webm"  # FFmpeg picks the container from the name
        writer = cv2.VideoWriter(str(file), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*codec), float(fps), even)
        if not writer.isOpened():
            raise RecondreamerError(f"{out}: OpenCV cannot write WebM with {codec} here (its FFmpeg lacks the encoder)")
        try:
            for frame in frames:
                padded = cv2.copyMakeBorder(frame, 0, even[1] - height, 0, even[0] - width, cv2.BORDER_CONSTANT, value=(255, 255, 255))
                writer.write(cv2.cvtColor(padded, cv2.COLOR_RGB2BGR))
        finally:
            writer.release()
        write_bytes_atomic(out, file.read_bytes())
    return out


def decode_video(path: Path) -> list[np.ndarray]:
    """Every frame of a video file as (H,W,3) uint8 RGB."""
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    frames = []
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    finally:
        capture.release()
    if not frames:
        raise RecondreamerError(f"{path}: no video frames could be decoded")
    return frames


def clip_page(video: Path, title: str, labels: Sequence[str], sources: Sequence[tuple[str, str]]) -> str:
    """A self-contained HTML page: the WebM video as a data URI (looping, muted, playing on load),
    what each panel is and where its frames come from."""
    data = base64.b64encode(video.read_bytes()).decode("ascii")
    rows = "".join(f"<li><b>{html.escape(label)}</b>: {html.escape(source)}</li>" for label, source in sources)
    alt = html.escape(f"{title}: " + ", ".join(labels))
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body {{ font-family: sans-serif; margin: 1em; }} video {{ max-width: 100%; }}</style></head>
<body>
<h2>{html.escape(title)}</h2>
<video src="data:video/webm;base64,{data}" aria-label="{alt}" autoplay loop muted playsinline controls></video>
<p>Panels, row by row:</p>
<ul>{rows}</ul>
</body></html>
"""


def novel_view_clip(scene_dir: str | Path, trajectory: str, panels: Sequence[tuple[str, Path]], out: str | Path, fps: float = 6.0,
                    min_panel_width: int = 240) -> tuple[Path, Path, Path]:
    """Write ``out`` (GIF) and its ``.webm`` and ``.html`` siblings; returns the three paths."""
    out = Path(out)
    if out.suffix.lower() != ".gif":
        raise RecondreamerError(f"--out {out}: expected a .gif file (the video and the page are written beside it as .webm and .html)")
    clips = clip_panels(scene_dir, trajectory, panels)
    images = compose_frames(clips, min_panel_width)
    video = encode_webm([np.asarray(image) for image in images], out.with_suffix(".webm"), fps)
    write_gif(images, out, fps)
    sources = [(label, str(directory)) for label, directory in panels]
    if clips[-1][0] == TRUTH_LABEL:
        sources.append((TRUTH_LABEL, f"rendered by the synthetic world ({Path(scene_dir) / 'novel' / trajectory})"))
    scene_name = Path(scene_dir).name
    page = clip_page(video, f"{scene_name}: {trajectory}", [label for label, _ in clips], sources)
    page_path = out.with_suffix(".html")
    write_text_atomic(page_path, page)
    return out, video, page_path

