#!/usr/bin/env bash
# The project's CUDA paths on one GPU, end to end, with timings (docs/gpu.md has the results).
#
# Stages (the first six by default, in this order; name some to run only those):
#   env       nvidia-smi, python, torch, gsplat versions
#   build     gsplat's CUDA extension (compiled by torch on first use; timed)
#   tests     the splat tests and tests/test_device.py with the CUDA tests enabled
#   recon     train-recon of a synthetic segment on CUDA with gsplat: the default preset, then
#             PAPER_ITERATIONS iterations of the paper preset (s/it and the ETA of its 50k)
#   restorer  the generative stack on CUDA: autoencoder and dd2 world model pretrained on two corpus
#             scenes (or AUTOENCODER / WORLD_MODEL given), restoration pairs of the recon stage's
#             default run, a dd2_mask fine-tuning of RESTORER_STEPS steps, and a 40-frame restore at
#             1 and 10 DDIM steps on CUDA and at 1 step on one CPU thread
#   raster    benchmarks/rasterizer.py: the C++ CPU kernel against the gsplat backend
#   capacity  (not in the default list; issue 6) does a wider DriveRestorer trained longer gain more on
#             held-out pairs? Street reconstructions (CPU, one thread each, in parallel) and restoration
#             pairs of CAP_TRAIN corpus scenes and of corpus-021/022 (held out), then three dd2 -> dd2_mask models on DEVICE: the CPU recipe
#             (default width, 1000 + 1000 steps), the default width trained longer, and a wide UNet
#             (CAP_WIDE channels) trained as long; the gate's held-out table for all three. Autoencoder:
#             CAP_AUTOENCODER (default results/restorer-dev/ae8_5000.pt; trained here when missing)
# Every stage prints a table; the work lands under DEV. A stage whose output exists is not redone,
# so the script can be re-run after an interruption. Needs a CUDA build of torch, gsplat (pip
# install 'recondreamer[cuda]'), nvcc and ninja.
#
# Usage: benchmarks/gpu_check.sh [STAGE...]
# Environment: DEV (default results/gpu-dev/check), PAPER_ITERATIONS (3000), RESTORER_STEPS (300),
#   AE_STEPS (1500), WM_STEPS (600), AUTOENCODER / WORLD_MODEL (checkpoints to use instead of
#   pretraining), TORCH_CUDA_ARCH_LIST (default: the GPU's own, e.g. 9.0 on an H100), MAX_JOBS (nvcc jobs);
#   for a quick dry run of the script itself on a CPU: DEVICE=cpu BACKEND=cpu DEFAULT_ITERATIONS=N (default:
#   the preset's) with small step counts. Capacity: CAP_TRAIN (8 scenes), CAP_WIDE ("64 128 256"),
#   CAP_WM_STEPS / CAP_RESTORER_STEPS of the CPU recipe (1000 1000), CAP_LONG_WM_STEPS /
#   CAP_LONG_RESTORER_STEPS of the longer runs (2000 1500), CAP_TIMESTEP_POWER of the restorers
#   (3; train-restorer's default is 50, docs/generative.md), CAP_CROP of the restorers'
#   training latents ("24 32", the default crop; "0 0" = whole latents, better on CPU: docs/generative.md),
#   CAP_PIXEL_LOSS_WEIGHT (0; see train-restorer --pixel-loss-weight), CAP_JOBS (parallel CPU jobs, nproc),
#   CAP_TRAJECTORIES of the pairs ("original shift@3 shift@6 lane_change"), CAP_CORPUS (the first 20 corpus
#   scenes pretrain the world models).
set -uo pipefail
cd "$(dirname "$0")/.."
DEV=${DEV:-results/gpu-dev/check}
PAPER_ITERATIONS=${PAPER_ITERATIONS:-3000}
RESTORER_STEPS=${RESTORER_STEPS:-300}
AE_STEPS=${AE_STEPS:-1500}
WM_STEPS=${WM_STEPS:-600}
RC="python3 -m recondreamer"
STAGES=${*:-env build tests recon restorer raster}
DEVICE=${DEVICE:-cuda}
BACKEND=${BACKEND:-gsplat}
DEFAULT_ITERATIONS=${DEFAULT_ITERATIONS:+--iterations $DEFAULT_ITERATIONS}
SEGMENT=$DEV/scenes/synth-01
mkdir -p "$DEV/logs"
export PYTHONUNBUFFERED=1
if [ -z "${TORCH_CUDA_ARCH_LIST:-}" ] && [ "$DEVICE" != cpu ]; then
  TORCH_CUDA_ARCH_LIST=$(python3 -c "import torch; print('%d.%d' % torch.cuda.get_device_capability())") && export TORCH_CUDA_ARCH_LIST
fi
export MAX_JOBS=${MAX_JOBS:-$(nproc)}

wants() { [[ " $STAGES " == *" $1 "* ]]; }
banner() { echo; echo "=== $1 ($(date +%T))"; }
timed() {  # timed LOG COMMAND...: run, log to LOG, print the wall seconds and the exit status
  local log=$1 start=$SECONDS; shift
  "$@" > "$log" 2>&1
  local status=$?
  echo "$((SECONDS - start)) s, exit $status: $*" | cut -c1-220
  return $status
}
last_progress() {  # the last progress line of a train-recon log: step, psnr, gaussians, s/it
  grep -E "step [0-9]+/[0-9]+ .* s/it" "$1" | tail -1 | sed -E 's/.*step ([0-9]+)\/([0-9]+) .*psnr ([0-9.]+) gaussians ([0-9]+).*\| ([0-9.]+) s\/it.*/\1 \2 \3 \4 \5/'
}

if wants env; then
  banner "environment"
  nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
  python3 - <<'EOF'
import platform, torch
print(f"python {platform.python_version()}, torch {torch.__version__} (CUDA {torch.version.cuda}), device {torch.cuda.get_device_name()}")
try:
    import gsplat
    print(f"gsplat {gsplat.__version__}")
except ImportError as error:
    print(f"gsplat missing: {error}")
EOF
  echo "TORCH_CUDA_ARCH_LIST=$TORCH_CUDA_ARCH_LIST MAX_JOBS=$MAX_JOBS"
fi

if wants build; then
  banner "gsplat CUDA extension build (torch JIT, first use)"
  python3 - <<'EOF'
import time
start = time.perf_counter()
from gsplat.cuda._backend import _C
print(f"gsplat extension ready in {time.perf_counter() - start:.1f} s ({'built' if _C is not None else 'FAILED'})")
EOF
fi

if wants tests; then
  banner "tests with the CUDA ones enabled"
  python3 -m pytest tests/test_splat_*.py tests/test_device.py -q -m "cuda or not cuda" -rs -p no:cacheprovider \
    > "$DEV/logs/tests.log" 2>&1
  echo "pytest exit $? (full log: $DEV/logs/tests.log)"
  grep -m 3 -E 'File ".*/tests/test_' "$DEV/logs/tests.log"  # the test a crash (signal) happened in, if any
  tail -15 "$DEV/logs/tests.log"
fi

if wants recon || wants restorer; then
  [ -d "$SEGMENT" ] || $RC synth --seed 101 --preset default --scene-id synth-01 --out "$SEGMENT" > "$DEV/logs/synth.log" 2>&1
fi

if wants recon; then
  banner "train-recon street on CUDA with gsplat (synth-01, 240x160, 40 frames)"
  [ -f "$DEV/runs/default/model.pt" ] || timed "$DEV/logs/recon_default.log" $RC train-recon --scene "$SEGMENT" --model street \
    --preset default $DEFAULT_ITERATIONS --device "$DEVICE" --backend "$BACKEND" --out "$DEV/runs/default"
  [ -f "$DEV/runs/paper/model.pt" ] || timed "$DEV/logs/recon_paper.log" $RC train-recon --scene "$SEGMENT" --model street \
    --preset paper --iterations "$PAPER_ITERATIONS" --device "$DEVICE" --backend "$BACKEND" --out "$DEV/runs/paper"
  printf "%-8s %10s %8s %10s %9s %14s\n" preset iterations psnr gaussians "s/it" "ETA 50k it"
  for preset in default paper; do
    read -r step total psnr gaussians sit <<< "$(last_progress "$DEV/runs/$preset/train.log")"
    eta=$(python3 -c "print(f'{${sit:-0} * 50000 / 60:.0f} min')")
    printf "%-8s %10s %8s %10s %9s %14s\n" "$preset" "$step/$total" "$psnr" "$gaussians" "$sit" "$eta"
  done
fi

if wants restorer; then
  banner "generative stack on CUDA"
  for i in 0 1; do
    [ -d "$DEV/corpus/corpus-00$i" ] || $RC synth --seed $((10000 + i)) --preset default --scene-id "corpus-00$i" \
      --out "$DEV/corpus/corpus-00$i" > "$DEV/logs/synth_corpus.log" 2>&1
  done
  AUTOENCODER=${AUTOENCODER:-$DEV/models/ae.pt}
  WORLD_MODEL=${WORLD_MODEL:-$DEV/models/wm_dd2.pt}
  mkdir -p "$DEV/models"
  [ -f "$AUTOENCODER" ] || timed "$DEV/logs/ae.log" $RC train-autoencoder --corpus "$DEV/corpus" --out "$AUTOENCODER" \
    --steps "$AE_STEPS" --latent-channels 8 --device "$DEVICE"
  [ -f "$WORLD_MODEL" ] || timed "$DEV/logs/wm.log" $RC pretrain-world-model --arch dd2 --corpus "$DEV/corpus" \
    --autoencoder "$AUTOENCODER" --out "$WORLD_MODEL" --steps "$WM_STEPS" --device "$DEVICE"
  [ -f "$DEV/pairs/synth-01__default.npz" ] || timed "$DEV/logs/pairs.log" $RC make-pairs --run "$DEV/runs/default" \
    --out "$DEV/pairs" --stages 4 --trajectories original shift@3 --threads 8
  [ -f "$DEV/models/restorer.pt" ] || timed "$DEV/logs/restorer.log" $RC train-restorer --arch dd2_mask \
    --world-model "$WORLD_MODEL" --pairs "$DEV/pairs" --out "$DEV/models/restorer.pt" --steps "$RESTORER_STEPS" --device "$DEVICE"
  [ -d "$DEV/renders/shift@3" ] || $RC render --run "$DEV/runs/default" --trajectory shift@3 --out "$DEV/renders/shift@3" \
    > "$DEV/logs/render.log" 2>&1
  for setting in "$DEVICE 1" "$DEVICE 10" "cpu 1"; do
    read -r device steps <<< "$setting"
    [ -d "$DEV/restored/$device-$steps" ] || timed "$DEV/logs/restore_$device-$steps.log" $RC restore --restorer "$DEV/models/restorer.pt" \
      --scene "$SEGMENT" --renders "$DEV/renders/shift@3" --trajectory shift@3 --sample-steps "$steps" --device "$device" --threads 1 \
      --out "$DEV/restored/$device-$steps"
  done
  python3 - "$DEV" "$DEVICE" <<'EOF'
import json, sys
from pathlib import Path
import numpy as np
from recondreamer.generative.checkpoint import load_checkpoint
from recondreamer.generative.frames_io import read_frames
from recondreamer.scene import load_scene

dev, device = Path(sys.argv[1]), sys.argv[2]
print(f"{'job':<28} {'steps':>6} {'ms/step':>8} {'final loss':>11}")
for name, kind in (("ae", "autoencoder"), ("wm_dd2", "world_model"), ("restorer", "restorer")):
    path = dev / "models" / f"{name}.pt"
    if path.is_file():
        metrics = load_checkpoint(path, kind)["metrics"]
        loss = metrics.get("final_loss", float("nan"))
        print(f"{kind + f' ({device})':<28} {metrics['steps']:>6} {metrics['ms_per_step']:>8.1f} {loss:>11.4f}")
scene = load_scene(dev / "scenes" / "synth-01")
truth = np.stack([scene.novel_image("shift@3", t) for t in range(scene.num_frames)])
render = read_frames(dev / "renders" / "shift@3")

def psnr(a, b):
    return 10 * np.log10(255.0**2 / np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))

print(f"\n40-frame shift@3 restore (restorer trained on this segment's own pairs: a smoke test, not a held-out score)")
print(f"{'device':<7} {'DDIM steps':>10} {'seconds':>8} {'s/step':>7} {'PSNR render':>12} {'PSNR restored':>14}")
for folder in sorted((dev / "restored").iterdir()):
    device, steps = folder.name.split("-")
    seconds = json.loads((folder / "info.json").read_text())["seconds"]
    restored = read_frames(folder)
    print(f"{device:<7} {steps:>10} {seconds:>8.2f} {seconds / int(steps):>7.3f} {psnr(render, truth):>12.2f} {psnr(restored, truth):>14.2f}")
EOF
fi

if wants raster; then
  banner "rasterizer: C++ CPU kernel (16 threads) vs gsplat"
  python3 benchmarks/rasterizer.py --skip-reference --threads 16 --counts 20000 100000 500000 --repeats 5
  python3 benchmarks/rasterizer.py --skip-reference --threads 16 --counts 100000 500000 --width 960 --height 640 --repeats 5
fi

if wants capacity; then
  banner "restorer capacity: CPU-sized vs wide dd2_mask on $DEVICE, gain on held-out pairs"
  CAP=$DEV/capacity
  CAP_TRAIN=${CAP_TRAIN:-8}
  CAP_WIDE=${CAP_WIDE:-64 128 256}
  CAP_JOBS=${CAP_JOBS:-$(nproc)}
  CAP_AUTOENCODER=${CAP_AUTOENCODER:-results/restorer-dev/ae8_5000.pt}
  CAP_TRAJECTORIES=${CAP_TRAJECTORIES:-original shift@3 shift@6 lane_change}
  TRAIN_SCENES=$(seq -f "corpus-%03g" 0 $((CAP_TRAIN - 1)))
  HELDOUT_SCENES="corpus-021 corpus-022"
  mkdir -p "$CAP/logs" "$CAP/corpus-train" "$CAP/models"
  # The corpus as the workflow makes it (seed 10000 + index); autoencoder and world models see 000..019.
  for i in $(seq 0 22); do printf "corpus-%03d %d\n" "$i" $((10000 + i)); done | xargs -P "$CAP_JOBS" -L 1 bash -c \
    '[ -d "$0/corpus/$1" ] || '"$RC"' synth --seed "$2" --preset default --scene-id "$1" --out "$0/corpus/$1" > "$0/logs/synth_$1.log" 2>&1' "$CAP"
  for i in $(seq 0 $((${CAP_CORPUS:-20} - 1))); do scene=$(printf "corpus-%03d" "$i"); ln -sfn "../corpus/$scene" "$CAP/corpus-train/$scene"; done
  if [ ! -f "$CAP_AUTOENCODER" ]; then
    CAP_AUTOENCODER=$CAP/models/ae8.pt
    [ -f "$CAP_AUTOENCODER" ] || timed "$CAP/logs/ae.log" $RC train-autoencoder --corpus "$CAP/corpus-train" --out "$CAP_AUTOENCODER" \
      --steps 5000 --latent-channels 8 --device "$DEVICE"
  fi
  declare -A WM_STEPS_OF=([small]=${CAP_WM_STEPS:-1000} [small_long]=${CAP_LONG_WM_STEPS:-2000} [wide]=${CAP_LONG_WM_STEPS:-2000})
  declare -A RESTORER_STEPS_OF=([small]=${CAP_RESTORER_STEPS:-1000} [small_long]=${CAP_LONG_RESTORER_STEPS:-1500} [wide]=${CAP_LONG_RESTORER_STEPS:-1500})
  declare -A CHANNELS_OF=([small]="" [small_long]="" [wide]="--channels $CAP_WIDE")
  # World models on the GPU while the reconstructions run on the CPU.
  for model in small small_long wide; do
    [ -f "$CAP/models/wm_$model.pt" ] || $RC pretrain-world-model --arch dd2 --corpus "$CAP/corpus-train" --autoencoder "$CAP_AUTOENCODER" \
      --out "$CAP/models/wm_$model.pt" --steps "${WM_STEPS_OF[$model]}" ${CHANNELS_OF[$model]} --device "$DEVICE" --threads 1 \
      > "$CAP/logs/wm_$model.log" 2>&1 &
  done
  start=$SECONDS
  for scene in $TRAIN_SCENES $HELDOUT_SCENES; do echo "$scene"; done | xargs -P "$CAP_JOBS" -I{} bash -c \
    '[ -f "$0/recon/{}/street/model.pt" ] || '"$RC"' train-recon --scene "$0/corpus/{}" --model street --preset default '"$DEFAULT_ITERATIONS"' --seed 0 \
      --threads 1 --out "$0/recon/{}/street" > "$0/logs/recon_{}.log" 2>&1' "$CAP"
  echo "reconstructions: $((SECONDS - start)) s"
  start=$SECONDS
  for scene in $TRAIN_SCENES; do echo "$scene pairs-train"; done > "$CAP/pairs_jobs.txt"
  for scene in $HELDOUT_SCENES; do echo "$scene pairs-heldout"; done >> "$CAP/pairs_jobs.txt"
  xargs -P "$CAP_JOBS" -L 1 bash -c '[ -f "$0/$2/$1__street.npz" ] || '"$RC"' make-pairs --run "$0/recon/$1/street" --out "$0/$2" \
    --stages 4 --trajectories '"$CAP_TRAJECTORIES"' --threads 1 > "$0/logs/pairs_$1.log" 2>&1' "$CAP" < "$CAP/pairs_jobs.txt"
  echo "pairs: $((SECONDS - start)) s"
  wait  # the world models
  grep -h "wrote" "$CAP"/logs/wm_*.log
  # The pairs' latents, encoded once for the three restorer jobs (data.pair_latents caches them).
  python3 - "$CAP_AUTOENCODER" "$DEVICE" "$CAP"/pairs-train/*.npz <<'EOF'
import sys
from pathlib import Path
from recondreamer.generative.data import load_pair_sequences
from recondreamer.generative.models import load_autoencoder
load_pair_sequences([Path(p) for p in sys.argv[3:]], load_autoencoder(sys.argv[1], sys.argv[2])[0], False, False)
EOF
  RESTORER_OPTIONS="--target-space residual --timestep-power ${CAP_TIMESTEP_POWER:-3} --residual-decoding on --sample-steps 1 --strength 1.0 --threads 1 --crop ${CAP_CROP:-24 32} --pixel-loss-weight ${CAP_PIXEL_LOSS_WEIGHT:-0}"
  for model in small small_long wide; do
    [ -f "$CAP/models/restorer_$model.pt" ] || $RC train-restorer --arch dd2_mask --world-model "$CAP/models/wm_$model.pt" \
      --pairs "$CAP/pairs-train" --out "$CAP/models/restorer_$model.pt" --steps "${RESTORER_STEPS_OF[$model]}" $RESTORER_OPTIONS \
      --device "$DEVICE" > "$CAP/logs/restorer_$model.log" 2>&1 &
  done
  wait
  grep -h "wrote" "$CAP"/logs/restorer_*.log
  # The gate's own evaluation (as benchmarks/restorer.py's: 2 stages per held-out pairs file, PSNR gain
  # and flicker of each restorer's default restore), with each restorer loaded onto DEVICE.
  python3 - "$CAP" "$DEVICE" <<'EOF'
import sys
from pathlib import Path
import torch
from recondreamer.generative.checkpoint import load_checkpoint
from recondreamer.generative.inference import load_restorer, restore_clip
from recondreamer.generative.scoring import score_clip, scored_clips, summarise

cap, device = Path(sys.argv[1]), sys.argv[2]
torch.set_num_threads(1)
files = sorted((cap / "pairs-heldout").glob("*.npz"))
print(f"held-out pairs: {', '.join(f.stem for f in files)}")
print(f"{'model':<11} {'channels':<14} {'params':>8} {'wm steps':>8} {'steps':>6} {'ms/step':>8} {'clips':>5} {'PSNR deg':>8} "
      f"{'PSNR rest':>9} {'gain dB':>7} {'orig':>6} {'novel':>6} {'flick deg':>9} {'flick rest':>10}")
for model in ("small", "small_long", "wide"):
    path = cap / "models" / f"restorer_{model}.pt"
    if not path.is_file():
        print(f"{model:<11} (missing: see {cap}/logs/restorer_{model}.log)")
        continue
    payload = load_checkpoint(path, "restorer")
    world = load_checkpoint(cap / "models" / f"wm_{model}.pt", "world_model")
    params = sum(t.numel() for t in payload["state"].values())
    restorer = load_restorer(path, device)
    row = summarise([score_clip(kind, degraded, restore_clip(restorer, degraded, structure), gt)
                     for kind, degraded, gt, structure in scored_clips(restorer, payload, files, 2)])
    channels = "x".join(map(str, payload["config"]["unet"]["channels"]))
    print(f"{model:<11} {channels:<14} {params / 1e6:>7.2f}M {world['metrics']['steps']:>8} {payload['metrics']['steps']:>6} "
          f"{payload['metrics']['ms_per_step']:>8.0f} {row['clips']:>5} {row['psnr_degraded']:>8.2f} {row['psnr_restored']:>9.2f} "
          f"{row['gain']:>7.2f} {row['gain_orig']:>6.2f} {row['gain_novel']:>6.2f} {row['flicker_degraded']:>9.2f} {row['flicker_restored']:>10.2f}")
EOF
fi
