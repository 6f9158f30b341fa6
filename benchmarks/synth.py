"""Time and peak memory of one default synthetic segment with its three true novel trajectories.

Target (issue 2): under 30 s and under 2 GB on a 2-core CPU machine. Prints a table: wall-clock
and CPU seconds per stage (CPU < wall means the machine was shared), then peak resident memory.

    python benchmarks/synth.py [--seed 101] [--preset default] [--out DIR]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path


def timed(function, *args, **kwargs):
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=101, help="world seed (default: 101, segment synth-01)")
    parser.add_argument("--preset", default="default", help="synthetic preset (default: default)")
    parser.add_argument("--out", help="scene directory to write (default: a temporary directory)")
    args = parser.parse_args()

    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment, make_config
    from recondreamer.sources.synthetic.render import render_view
    from recondreamer.sources.synthetic.segment import camera_intrinsics, camera_to_ego, lidar_scan
    from recondreamer.sources.synthetic.world import build_world

    config = make_config(args.preset)
    rows = []
    world, wall, cpu = timed(build_world, args.seed)
    rows.append(("build world", wall, cpu))
    prims = world.primitives_at(0.0)
    cam = world.ego_pose(0.0) @ camera_to_ego(config)
    K = camera_intrinsics(config)
    repeats = 10
    _, wall, cpu = timed(lambda: [render_view(world, prims, cam, K, config.width, config.height) for _ in range(repeats)])
    rows.append((f"one camera view {config.width}x{config.height} (mean of {repeats})", wall / repeats, cpu / repeats))
    _, wall, cpu = timed(lambda: [lidar_scan(world, 0.0, config) for _ in range(repeats)])
    rows.append((f"one LiDAR sweep {config.lidar_beams}x{config.lidar_azimuths} (mean of {repeats})", wall / repeats, cpu / repeats))

    data, gen_wall, gen_cpu = timed(generate_segment, args.seed, args.preset)
    views = data.num_frames * (1 + len(data.novel))
    rows.append((f"generate_segment: {data.num_frames} frames, {views} views + LiDAR", gen_wall, gen_cpu))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp) / "scene"
        _, write_wall, write_cpu = timed(write_scene, out, data)
        rows.append(("write_scene (PNG + npy + JSON, validated)", write_wall, write_cpu))
    rows.append(("segment total (generate + write)", gen_wall + write_wall, gen_cpu + write_cpu))
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB

    width = max(len(name) for name, _, _ in rows)
    print(f"synthetic segment benchmark: seed {args.seed}, preset {args.preset}")
    print(f"{'stage':<{width}}  {'wall s':>8}  {'CPU s':>8}")
    for name, wall, cpu in rows:
        print(f"{name:<{width}}  {wall:8.3f}  {cpu:8.3f}")
    print(f"{'peak resident memory (MiB)':<{width}}  {peak_mib:8.0f}")
    total = gen_wall + write_wall
    print(f"target: under 30 s and 2048 MiB -> {'met' if total < 30 and peak_mib < 2048 else 'NOT met'} (wall {total:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
