"""OpenCV against the project's current image code: decoding, encoding, resizing, colour conversion
and the report clips' animation, on the images the project handles.

    python benchmarks/opencv_images.py [--repeat 7]

Images: a synthetic segment's frame at the compact preset's 240x160 (the default workflow's size)
and the real Waymo FRONT frame (1920x1280, ../shared/data/waymo/; a synthetic frame enlarged to
1920x1280 where the file is absent). Times are the best of --repeat runs, per call, in
milliseconds, one thread (cv2.setNumThreads(1), as every workflow job runs). "same pixels": the
largest absolute difference between the two results (decoders: both outputs RGB).

Clips: the novel-view clip of recondreamer/report/clips.py (four panels of a quick synthetic
segment's frames, enlarged to 240 pixels wide, 12 frames) as the GIF of write_gif (Pillow, octree
palettes) and as WebM by OpenCV's VideoWriter (VP8, VP9); PSNR of the decoded animation against
the composed frames.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from recondreamer.report import clips
from recondreamer.sources.synthetic import generate_segment

WAYMO = Path(__file__).resolve().parents[2] / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def best_ms(function, repeat: int) -> float:
    function()  # warm-up
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1000 * min(times)


def largest_difference(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.abs(a.astype(np.int32) - b.astype(np.int32)).max())


def pil_jpeg(rgb: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="JPEG", quality=95)
    return buffer.getvalue()


def pil_png(rgb: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def pil_decode(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as image:
        return np.asarray(image.convert("RGB"))


def cv_decode(data: bytes) -> np.ndarray:
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def cv_png(rgb: np.ndarray) -> bytes:
    return cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()


def cv_jpeg(rgb: np.ndarray) -> bytes:
    return cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def waymo_jpeg(fallback: np.ndarray) -> tuple[str, bytes]:
    if WAYMO.is_file():
        from recondreamer.sources.waymo import schema
        from recondreamer.sources.waymo.tfrecord import iter_records

        frame = schema.Frame.FromString(next(iter_records(WAYMO)))
        return "Waymo FRONT 1920x1280", next(image.image for image in frame.images if image.name == schema.CAMERA_NAMES["FRONT"])
    enlarged = cv2.resize(fallback, (1920, 1280), interpolation=cv2.INTER_CUBIC)
    return "synthetic 1920x1280", pil_jpeg(enlarged)


def image_rows(repeat: int) -> list[tuple[str, str, float, float, str]]:
    small = generate_segment(101, "compact", frames=1, novel_views=False).frames.images[0]  # (160,240,3)
    waymo_name, waymo = waymo_jpeg(small)
    large = pil_decode(waymo)
    rows = []
    for name, rgb, jpeg in (("240x160", small, pil_jpeg(small)), (waymo_name, large, waymo)):
        png = pil_png(rgb)
        rows.append((f"JPEG decode, {name}", "Pillow", best_ms(lambda: pil_decode(jpeg), repeat), best_ms(lambda: cv_decode(jpeg), repeat),
                     f"same pixels: {largest_difference(pil_decode(jpeg), cv_decode(jpeg))}"))
        rows.append((f"PNG decode, {name}", "Pillow", best_ms(lambda: pil_decode(png), repeat), best_ms(lambda: cv_decode(png), repeat),
                     f"same pixels: {largest_difference(pil_decode(png), cv_decode(png))}"))
        rows.append((f"PNG encode (level 1), {name}", "Pillow", best_ms(lambda: pil_png(rgb), repeat), best_ms(lambda: cv_png(rgb), repeat),
                     f"bytes {len(pil_png(rgb))} / {len(cv_png(rgb))}"))
        rows.append((f"JPEG encode (quality 95), {name}", "Pillow", best_ms(lambda: pil_jpeg(rgb), repeat), best_ms(lambda: cv_jpeg(rgb), repeat),
                     f"bytes {len(pil_jpeg(rgb))} / {len(cv_jpeg(rgb))}"))
    rgba = np.dstack([large, np.full(large.shape[:2], 255, np.uint8)])
    rows.append(("RGBA -> RGB, 1920x1280", "Pillow convert", best_ms(lambda: np.asarray(Image.fromarray(rgba).convert("RGB")), repeat),
                 best_ms(lambda: cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), repeat), "same pixels: 0" if np.array_equal(
                     np.asarray(Image.fromarray(rgba).convert("RGB")), cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)) else "differ"))
    rows.append(("RGB -> BGR, 1920x1280", "numpy [..., ::-1] copy", best_ms(lambda: np.ascontiguousarray(large[..., ::-1]), repeat),
                 best_ms(lambda: cv2.cvtColor(large, cv2.COLOR_RGB2BGR), repeat), "same pixels: 0"))
    factor = 3  # clips: 96x64 quick frames enlarged to at least 240 wide
    quick = small[::2, ::2].copy()
    pil_nearest = lambda: np.asarray(Image.fromarray(quick).resize((quick.shape[1] * factor, quick.shape[0] * factor), Image.Resampling.NEAREST))  # noqa: E731
    cv_nearest = lambda: cv2.resize(quick, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST_EXACT)  # noqa: E731
    rows.append(("nearest x3 (clip panel), 120x80", "Pillow resize", best_ms(pil_nearest, repeat), best_ms(cv_nearest, repeat),
                 f"same pixels: {largest_difference(pil_nearest(), cv_nearest())}"))
    image = torch.from_numpy(large.astype(np.float32) / 255)
    pooled = lambda: F.avg_pool2d(image.permute(2, 0, 1)[None], 2)[0].permute(1, 2, 0).contiguous()  # noqa: E731
    area = lambda: cv2.resize(image.numpy(), (960, 640), interpolation=cv2.INTER_AREA)  # noqa: E731
    rows.append(("area /2 float32, 1920x1280", "torch avg_pool2d", best_ms(pooled, repeat), best_ms(area, repeat),
                 f"largest difference {np.abs(pooled().numpy() - area()).max():.1e}"))
    return rows


def clip_frames() -> list[np.ndarray]:
    segment = generate_segment(7, "quick", frames=12)
    views = np.stack(segment.frames.images)
    novel = np.stack(next(iter(segment.novel.values())).images)
    panels = [("recorded", views), ("novel", novel), ("recorded, darker", views // 2), ("novel, darker", novel // 2)]
    return [np.asarray(image) for image in clips.compose_frames(panels)]


def psnr(reference: list[np.ndarray], decoded: list[np.ndarray]) -> float:
    if len(decoded) != len(reference):
        raise AssertionError(f"decoded {len(decoded)} frames of {len(reference)}")
    mse = np.mean([np.mean((a.astype(np.float64) - b) ** 2) for a, b in zip(reference, decoded)])
    return 10 * np.log10(255**2 / mse)


def clip_rows(repeat: int) -> list[tuple[str, float, int, float]]:
    frames = clip_frames()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        gif = Path(tmp) / "clip.gif"
        seconds = best_ms(lambda: clips.write_gif([Image.fromarray(f) for f in frames], gif, 6.0), repeat)
        with Image.open(gif) as image:
            decoded = []
            for index in range(image.n_frames):
                image.seek(index)
                decoded.append(np.asarray(image.convert("RGB")))
        rows.append(("GIF (Pillow, octree palettes)", seconds, gif.stat().st_size, psnr(frames, decoded)))
        for codec in ("VP80", "VP90"):
            webm = Path(tmp) / f"clip-{codec}.webm"
            seconds = best_ms(lambda: clips.encode_webm(frames, webm, 6.0, codec), repeat)
            rows.append((f"WebM {codec[:3]} (OpenCV VideoWriter)", seconds, webm.stat().st_size, psnr(frames, clips.decode_video(webm))))
    return rows, frames[0].shape


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    print(f"OpenCV {cv2.__version__}, Pillow {Image.__version__}, torch {torch.__version__}; best of {args.repeat}, ms per call\n")
    print("| operation | current | current ms | OpenCV ms | OpenCV / current | check |")
    print("|---|---|---|---|---|---|")
    for operation, current, ours, opencv, check in image_rows(args.repeat):
        print(f"| {operation} | {current} | {ours:.2f} | {opencv:.2f} | {opencv / ours:.2f} | {check} |")
    rows, shape = clip_rows(args.repeat)
    print(f"\nNovel-view clip, 12 frames of {shape[1]}x{shape[0]} (four panels), 6 fps:\n")
    print("| format | write ms | bytes | PSNR dB |")
    print("|---|---|---|---|")
    for name, ms, size, quality in rows:
        print(f"| {name} | {ms:.0f} | {size:,} | {quality:.1f} |")


if __name__ == "__main__":
    main()
