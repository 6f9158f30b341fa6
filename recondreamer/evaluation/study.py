"""The preference study (the paper's table 3): an automatic judge, a static study page, win rates.

Clip = one scene seen along one trajectory, rendered by two methods. People compare the two
videos on a static HTML page (top/bottom placement drawn at random and recorded in
``placement.json``, never shown on the page) and download their choices as a CSV
(``participant,clip_id,choice,time``, choice = top | bottom). ``study-ingest`` joins the CSVs
with the placement file and counts wins per trajectory. The automatic judge decides each pair
by closeness to the true novel view (synthetic scenes) and feeds the same win-rate counter.
"""

from __future__ import annotations

import csv
import html
import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from recondreamer.errors import RecondreamerError
from recondreamer.evaluation import image_metrics
from recondreamer.frames_io import frame_files
from recondreamer.io import atomic_path, write_text_atomic

JUDGE_METRICS = ("ssim", "psnr")
CSV_FIELDS = ("participant", "clip_id", "choice", "time")


@dataclass(frozen=True)
class Comparison:
    """One decided pair: ``winner`` is a method name, or None for a tie."""

    trajectory: str
    method_a: str
    method_b: str
    winner: str | None


# ---------------------------------------------------------------------------- automatic judge


def clip_score(frames: np.ndarray, truth: np.ndarray, metric: str) -> float:  # (T,H,W,3) x2
    """Closeness of a clip to the truth: mean per-frame SSIM (default) or mean per-frame PSNR (capped at 100 dB)."""
    if metric == "ssim":
        return float(np.mean([image_metrics.ssim(f, g) for f, g in zip(frames, truth, strict=True)]))
    if metric == "psnr":
        return float(np.mean([min(image_metrics.psnr(f, g), 100.0) for f, g in zip(frames, truth, strict=True)]))
    raise ValueError(f"unknown judge metric {metric!r}; expected one of {JUDGE_METRICS}")


def judge_pair(truth: np.ndarray, frames_a: np.ndarray, frames_b: np.ndarray, metric: str = "ssim", tie_tolerance: float = 1e-6) -> tuple[str, float, float]:
    """'a', 'b' or 'tie' for the clip closer to ``truth``, with both scores."""
    score_a, score_b = clip_score(frames_a, truth, metric), clip_score(frames_b, truth, metric)
    if abs(score_a - score_b) <= tie_tolerance:
        return "tie", score_a, score_b
    return ("a" if score_a > score_b else "b"), score_a, score_b


# ---------------------------------------------------------------------------- win rates


def win_rates(comparisons: Iterable[Comparison]) -> dict:
    """Win rate of each method against each other method, per trajectory and averaged over trajectories.

    Win rate = (wins + ties / 2) / comparisons. The average is the mean of the per-trajectory
    rates (as the paper's table 3 averages its rows).
    """
    counts: dict[tuple[str, str], dict[str, dict[str, int]]] = {}
    for c in comparisons:
        for method, other in ((c.method_a, c.method_b), (c.method_b, c.method_a)):
            row = counts.setdefault((method, other), {}).setdefault(c.trajectory, {"wins": 0, "losses": 0, "ties": 0})
            if c.winner is None:
                row["ties"] += 1
            elif c.winner == method:
                row["wins"] += 1
            else:
                row["losses"] += 1
    pairs = []
    for (method, other), by_trajectory in sorted(counts.items()):
        per_trajectory = {}
        for trajectory, row in sorted(by_trajectory.items()):
            total = row["wins"] + row["losses"] + row["ties"]
            per_trajectory[trajectory] = {**row, "comparisons": total, "win_rate": (row["wins"] + row["ties"] / 2) / total}
        rates = [v["win_rate"] for v in per_trajectory.values()]
        pairs.append({"method": method, "versus": other, "per_trajectory": per_trajectory, "average": float(np.mean(rates))})
    return {"pairs": pairs}


# ---------------------------------------------------------------------------- study page


@dataclass(frozen=True)
class Clip:
    label: str  # scene name shown to nobody; kept in placement.json
    trajectory: str
    methods: tuple[tuple[str, Path], tuple[str, Path]]  # (name, render directory) x 2


def parse_method(text: str) -> tuple[str, Path]:
    """'NAME=DIR' -> (NAME, DIR); RecondreamerError naming the argument otherwise."""
    name, sep, directory = text.partition("=")
    if not sep or not name or not directory:
        raise RecondreamerError(f"method {text!r}: expected NAME=DIRECTORY")
    return name, Path(directory)


def write_animation(directory: Path, out: Path, fps: float, max_width: int | None) -> None:
    """An animated WebP or GIF (by ``out``'s suffix) of a directory of numbered frames."""
    frames = []
    for path in frame_files(directory):
        with Image.open(path) as image:
            frame = image.convert("RGB")
        if max_width and frame.width > max_width:
            frame = frame.resize((max_width, round(frame.height * max_width / frame.width)), Image.Resampling.LANCZOS)
        frames.append(frame)
    duration = int(round(1000.0 / fps))
    options = {"lossless": False, "quality": 90} if out.suffix == ".webp" else {}
    with atomic_path(out) as tmp:
        frames[0].save(tmp, format="WEBP" if out.suffix == ".webp" else "GIF", save_all=True, append_images=frames[1:], duration=duration, loop=0, **options)


def build_study_page(clips: Sequence[Clip], out: str | Path, seed: int = 0, fps: float = 10.0, media_format: str = "webp", max_width: int | None = None, title: str = "Which video looks better?") -> dict:
    """Write ``out/index.html``, ``out/media/*`` and ``out/placement.json``; returns the placement."""
    if not clips:
        raise RecondreamerError("the study page needs at least one clip")
    if media_format not in ("webp", "gif"):
        raise RecondreamerError(f"media format {media_format!r}: expected webp or gif")
    out = Path(out)
    (out / "media").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(clips))
    placement = {"seed": seed, "clips": []}
    for position, index in enumerate(order):
        clip = clips[int(index)]
        swap = bool(rng.random() < 0.5)
        top, bottom = (clip.methods[1], clip.methods[0]) if swap else clip.methods
        clip_id = f"clip{position:03d}"
        for slot, (_, directory) in (("top", top), ("bottom", bottom)):
            write_animation(directory, out / "media" / f"{clip_id}_{slot}.{media_format}", fps, max_width)
        placement["clips"].append({"clip_id": clip_id, "scene": clip.label, "trajectory": clip.trajectory, "top": top[0], "bottom": bottom[0], "top_dir": str(top[1]), "bottom_dir": str(bottom[1])})
    write_text_atomic(out / "placement.json", json.dumps(placement, indent=2) + "\n")
    write_text_atomic(out / "index.html", _page_html([c["clip_id"] for c in placement["clips"]], media_format, title))
    return placement


def _page_html(clip_ids: Sequence[str], media_format: str, title: str) -> str:
    """Self-contained page: inline CSS and JS, media by relative path, no network access."""
    sections = []
    for number, clip_id in enumerate(clip_ids, start=1):
        sections.append(
            f"""<section class="clip" id="{clip_id}">
<h2>Clip {number} of {len(clip_ids)}</h2>
<figure><figcaption>Top</figcaption><img src="media/{clip_id}_top.{media_format}" alt="top video of clip {number}"></figure>
<figure><figcaption>Bottom</figcaption><img src="media/{clip_id}_bottom.{media_format}" alt="bottom video of clip {number}"></figure>
<p><label><input type="radio" name="{clip_id}" value="top"> Top is better</label>
<label><input type="radio" name="{clip_id}" value="bottom"> Bottom is better</label></p>
</section>"""
        )
    ids = json.dumps(list(clip_ids))
    fields = ",".join(CSV_FIELDS)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>
body {{ font-family: sans-serif; max-width: 60em; margin: 1em auto; padding: 0 1em; }}
figure {{ margin: 0.5em 0; }} img {{ max-width: 100%; image-rendering: auto; }}
section.clip {{ border-top: 1px solid #999; padding: 0.5em 0; }}
#status {{ font-weight: bold; }}
</style></head>
<body>
<h1>{html.escape(title)}</h1>
<p>Each clip shows the same drive rendered two ways. Judge the whole video: a clean, steady
background, sharp lane lines and vehicles where they belong, no ghosting. Pick the better one,
then press <em>Download choices</em> at the end and send the CSV file back.</p>
<p><label>Your name or code: <input id="participant" type="text" size="20"></label></p>
{chr(10).join(sections)}
<p><button id="download" type="button">Download choices (CSV)</button> <span id="status"></span></p>
<script>
"use strict";
const clipIds = {ids};
const chosenAt = {{}};
document.addEventListener("change", (event) => {{
  if (event.target.type === "radio") {{ chosenAt[event.target.name] = new Date().toISOString(); }}
}});
function quote(text) {{ return '"' + String(text).replace(/"/g, '""') + '"'; }}
document.getElementById("download").addEventListener("click", () => {{
  const participant = document.getElementById("participant").value.trim() || "anonymous";
  const rows = ["{fields}"];
  let answered = 0;
  for (const id of clipIds) {{
    const picked = document.querySelector('input[name="' + id + '"]:checked');
    if (!picked) continue;
    answered += 1;
    rows.push([quote(participant), id, picked.value, chosenAt[id] || ""].join(","));
  }}
  const blob = new Blob([rows.join("\\n") + "\\n"], {{ type: "text/csv" }});
  const link = document.createElement("a");
  link.href = URL.createObjectURL(blob);
  link.download = "study-" + participant.replace(/[^A-Za-z0-9_-]/g, "_") + ".csv";
  document.body.appendChild(link);
  link.click();
  link.remove();
  document.getElementById("status").textContent = answered + " of " + clipIds.length + " clips answered and saved.";
}});
</script>
</body></html>
"""


def read_study_csvs(csv_paths: Sequence[str | Path], placement_path: str | Path) -> list[Comparison]:
    """Choices of the downloaded CSVs joined with the placement file; one comparison per row.

    A participant who answered a clip twice (in two files) counts once, with the later answer.
    """
    placement_path = Path(placement_path)
    try:
        placement = json.loads(placement_path.read_text())
        clips = {c["clip_id"]: c for c in placement["clips"]}
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise RecondreamerError(f"{placement_path}: not a study placement file ({error})") from None
    answers: dict[tuple[str, str], str] = {}
    for path in map(Path, csv_paths):
        try:
            with open(path, newline="") as handle:
                reader = csv.DictReader(handle)
                missing = set(CSV_FIELDS[:3]) - set(reader.fieldnames or ())
                if missing:
                    raise RecondreamerError(f"{path}: missing CSV columns {sorted(missing)} (expected {','.join(CSV_FIELDS)})")
                for line, row in enumerate(reader, start=2):
                    if any(row.get(name) is None for name in CSV_FIELDS[:3]):
                        given = sum(value is not None for value in row.values())
                        raise RecondreamerError(f"{path}:{line}: row cut short ({given} of {len(reader.fieldnames)} fields; an interrupted download?)")
                    if row["clip_id"] not in clips:
                        raise RecondreamerError(f"{path}:{line}: clip {row['clip_id']!r} is not in {placement_path}")
                    if row["choice"] not in ("top", "bottom"):
                        raise RecondreamerError(f"{path}:{line}: choice {row['choice']!r} is not 'top' or 'bottom'")
                    answers[(row["participant"], row["clip_id"])] = row["choice"]
        except OSError as error:
            raise RecondreamerError(f"{path}: cannot read ({error.strerror})") from None
        except (UnicodeDecodeError, csv.Error) as error:  # binary or garbled bytes: not the page's download
            raise RecondreamerError(f"{path}: not a study CSV file ({error})") from None
    comparisons = []
    for (_, clip_id), choice in sorted(answers.items()):
        clip = clips[clip_id]
        comparisons.append(Comparison(clip["trajectory"], clip["top"], clip["bottom"], clip[choice]))
    return comparisons
