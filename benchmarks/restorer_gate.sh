#!/usr/bin/env bash
# Rebuilds the generative stack's quality gates from scratch (issue 6), under results/restorer-dev/,
# exactly as the session-7 table in docs/restorer.md was made: autoencoder, street reconstructions
# and restoration pairs of training and held-out corpus scenes, the three world models, the four
# residual DriveRestorers (3000 steps each, trained at the step a 1-step restore samples), a
# dd2_mask restorer trained 8000 steps, and the side-by-side gate table.
#
# Splits: autoencoder and world models train on corpus-000..019; restorers on pairs of
# corpus-000..012 (session 11's runs also on MORE_SCENES, corpus-013..019 and 023..060); the gate
# uses pairs of corpus-021 and corpus-022, which no model saw.
# Every step is an ordinary CLI command with one torch thread, run one after another (the
# machine is shared); a finished step is skipped when its output exists, so the script can be
# re-run after an interruption.
#
# Usage: benchmarks/restorer_gate.sh   (its last parts add the session-8 to -23 runs under results/restorer-dev/s8/ .. s23/)
set -euo pipefail
cd "$(dirname "$0")/.."
DEV=results/restorer-dev
RC="python -m recondreamer"
TRAIN_SCENES=$(seq -f "corpus-%03g" 0 12)
HELDOUT_SCENES="corpus-021 corpus-022"
MORE_SCENES=$(seq -f "corpus-%03g" 13 19; seq -f "corpus-%03g" 23 60)  # session 11: 45 more training scenes
TRAJECTORIES="original shift@3 shift@6 lane_change"
AE=$DEV/ae8_5000.pt
WM=$DEV/long            # world models (1000 steps each on ae8_5000.pt)
OUT=$DEV/s7             # restorers, logs and the gate table
RESTORER_STEPS=3000     # every backbone (25 CPU min for dd2_mask); dd2_mask also 8000 below
# Timestep power 50: training steps drawn with density ~ t^49, 95% of them above t = 940, i.e. the
# restorer learns the one step it samples (t = 999); power 3 at 3000 steps gained 0.22 dB less.
# One noise draw per restore, as every restorer here was scored (train-restorer stores 4 averaged
# draws by default since session 23; the session-23 part scores both).
RESTORER_OPTIONS="--target-space residual --timestep-power 50 --residual-decoding on --sample-steps 1 --samples 1 --strength 1.0 --threads 1"
mkdir -p results/corpus "$DEV/corpus-train" "$DEV/recon" "$DEV/pairs-train" "$DEV/pairs-heldout" "$DEV/logs" "$WM" "$OUT"

run() {  # run OUTPUT LOG COMMAND...: skip when OUTPUT exists
  local out=$1 log=$2; shift 2
  if [ -e "$out" ]; then echo "have $out"; return; fi
  echo "$(date +%T) make $out"
  "$@" > "$log" 2>&1
}

# The corpus scenes, as config/full.yaml's workflow makes them (seed 10000 + index, default preset);
# a finished full run's results/corpus is used as it is.
for i in $(seq 0 19) $(seq 21 60); do
  scene=$(printf "corpus-%03d" "$i")
  run "results/corpus/$scene" "$DEV/logs/synth_$scene.log" $RC synth --seed $((10000 + i)) --preset default \
    --scene-id "$scene" --out "results/corpus/$scene"
done
# The autoencoder and the world models see corpus-000..019 only.
for i in $(seq -w 0 19); do ln -sfn "../../corpus/corpus-0$i" "$DEV/corpus-train/corpus-0$i"; done

run "$AE" "$DEV/logs/ae8_5000.log" $RC train-autoencoder --corpus "$DEV/corpus-train" --out "$AE" \
  --steps 5000 --latent-channels 8 --threads 1

for scene in $TRAIN_SCENES $MORE_SCENES $HELDOUT_SCENES; do
  run "$DEV/recon/$scene/street/model.pt" "$DEV/logs/recon_$scene.log" $RC train-recon --scene "results/corpus/$scene" \
    --model street --preset default --seed 0 --threads 1 --out "$DEV/recon/$scene/street"
done
for scene in $TRAIN_SCENES $MORE_SCENES; do
  run "$DEV/pairs-train/${scene}__street.npz" "$DEV/logs/pairs_$scene.log" $RC make-pairs --run "$DEV/recon/$scene/street" \
    --out "$DEV/pairs-train" --stages 4 --trajectories $TRAJECTORIES --threads 1
done
for scene in $HELDOUT_SCENES; do
  run "$DEV/pairs-heldout/${scene}__street.npz" "$DEV/logs/pairs_$scene.log" $RC make-pairs --run "$DEV/recon/$scene/street" \
    --out "$DEV/pairs-heldout" --stages 4 --trajectories $TRAJECTORIES --threads 1
done

for arch in sd svd dd2; do
  run "$WM/wm_$arch.pt" "$WM/wm_$arch.log" $RC pretrain-world-model --arch "$arch" --corpus "$DEV/corpus-train" \
    --autoencoder "$AE" --out "$WM/wm_$arch.pt" --steps 1000 --threads 1
done

PAIRS=$(for scene in $TRAIN_SCENES; do ls "$DEV/pairs-train/${scene}"__*.npz; done)
# The pairs' latents are encoded once and cached next to them (data.pair_latents), so the
# restorer jobs below time their fine-tuning, not the shared encoding (about 5 CPU minutes).
python - $PAIRS <<EOF
import sys
from pathlib import Path
import torch
torch.set_num_threads(1)
from recondreamer.restorer.data import load_pair_sequences
from recondreamer.restorer.models import load_autoencoder
load_pair_sequences([Path(p) for p in sys.argv[1:]], load_autoencoder("$AE")[0], False, False)
EOF

for arch in dd2_mask sd dd2 svd; do
  world=$arch; [ "$arch" = dd2_mask ] && world=dd2
  run "$OUT/restorer_$arch.pt" "$OUT/restorer_$arch.log" $RC train-restorer --arch "$arch" --world-model "$WM/wm_$world.pt" \
    --pairs $PAIRS --out "$OUT/restorer_$arch.pt" --steps "$RESTORER_STEPS" $RESTORER_OPTIONS
done
run "$OUT/restorer_dd2_mask_8000.pt" "$OUT/restorer_dd2_mask_8000.log" $RC train-restorer --arch dd2_mask \
  --world-model "$WM/wm_dd2.pt" --pairs $PAIRS --out "$OUT/restorer_dd2_mask_8000.pt" --steps 8000 $RESTORER_OPTIONS

# The gate table: all four backbones at 1 DDIM step (the stored default), two stages (earliest,
# latest) per held-out pairs file: 16 clips of 40 frames per backbone; then the 8000-step dd2_mask.
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer sd="$OUT/restorer_sd.pt" svd="$OUT/restorer_svd.pt" dd2="$OUT/restorer_dd2.pt" dd2_mask="$OUT/restorer_dd2_mask.pt" \
  dd2_mask="$OUT/restorer_dd2_mask_8000.pt" | tee "$OUT/gate_table.txt"

# Session 8 (docs/restorer.md, "Results (session 8)"): the latent oracle of the held-out pairs, a
# dd2_mask restorer on whole latents for 3000 steps, one with the image-space loss, and the
# 8000-step restorer trained further on whole latents (--init-restorer), then two ways on from that.
S8=$DEV/s8
mkdir -p "$S8"
python benchmarks/pairs_error.py --pairs "$DEV/pairs-heldout" --autoencoder "$AE" | tee "$S8/pairs_error_oracle.txt"
run "$S8/whole_3000.pt" "$S8/whole_3000.log" $RC train-restorer --arch dd2_mask --world-model "$WM/wm_dd2.pt" \
  --pairs $PAIRS --out "$S8/whole_3000.pt" --steps 3000 --crop 0 0 $RESTORER_OPTIONS
run "$S8/px50_1000.pt" "$S8/px50_1000.log" $RC train-restorer --arch dd2_mask --world-model "$WM/wm_dd2.pt" \
  --pairs $PAIRS --out "$S8/px50_1000.pt" --steps 1000 --pixel-loss-weight 50 $RESTORER_OPTIONS
run "$S8/from8000_whole_1500.pt" "$S8/from8000_whole_1500.log" $RC train-restorer --arch dd2_mask --world-model "$WM/wm_dd2.pt" \
  --init-restorer "$OUT/restorer_dd2_mask_8000.pt" --pairs $PAIRS --out "$S8/from8000_whole_1500.pt" --steps 1500 --crop 0 0 \
  --learning-rate 5e-4 $RESTORER_OPTIONS
# Two ways on from the 9500-step restorer, side by side: plain whole-latent steps, and the image-space loss.
run "$S8/from9500_whole_2000.pt" "$S8/from9500_whole_2000.log" $RC train-restorer --arch dd2_mask --world-model "$WM/wm_dd2.pt" \
  --init-restorer "$S8/from8000_whole_1500.pt" --pairs $PAIRS --out "$S8/from9500_whole_2000.pt" --steps 2000 --crop 0 0 \
  --learning-rate 5e-4 $RESTORER_OPTIONS
run "$S8/from9500_whole_px50_900.pt" "$S8/from9500_whole_px50_900.log" $RC train-restorer --arch dd2_mask \
  --world-model "$WM/wm_dd2.pt" --init-restorer "$S8/from8000_whole_1500.pt" --pairs $PAIRS \
  --out "$S8/from9500_whole_px50_900.pt" --steps 900 --crop 0 0 --learning-rate 5e-4 --pixel-loss-weight 50 $RESTORER_OPTIONS
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S8/px50_1000.pt" dd2_mask="$S8/whole_3000.pt" dd2_mask="$S8/from8000_whole_1500.pt" \
  dd2_mask="$S8/from9500_whole_2000.pt" dd2_mask="$S8/from9500_whole_px50_900.pt" | tee "$S8/gate_table.txt"

# Session 9 (docs/restorer.md, "Results (session 9)"): the best restorer trained further with a
# heavier image-space loss (weight 200, then 1000 or a lower learning rate), and inference-time variants of one restorer.
S9=$DEV/s9
mkdir -p "$S9"
run "$S9/from10400_px200_700.pt" "$S9/from10400_px200_700.log" $RC train-restorer --arch dd2_mask \
  --world-model "$WM/wm_dd2.pt" --init-restorer "$S8/from9500_whole_px50_900.pt" --pairs $PAIRS \
  --out "$S9/from10400_px200_700.pt" --steps 700 --crop 0 0 --learning-rate 5e-4 --pixel-loss-weight 200 $RESTORER_OPTIONS
run "$S9/from11100_px1000_600.pt" "$S9/from11100_px1000_600.log" $RC train-restorer --arch dd2_mask \
  --world-model "$WM/wm_dd2.pt" --init-restorer "$S9/from10400_px200_700.pt" --pairs $PAIRS \
  --out "$S9/from11100_px1000_600.pt" --steps 600 --crop 0 0 --learning-rate 5e-4 --pixel-loss-weight 1000 $RESTORER_OPTIONS
run "$S9/from11100_px200_700_lr2.5e-4.pt" "$S9/from11100_px200_700_lr2.5e-4.log" $RC train-restorer --arch dd2_mask \
  --world-model "$WM/wm_dd2.pt" --init-restorer "$S9/from10400_px200_700.pt" --pairs $PAIRS \
  --out "$S9/from11100_px200_700_lr2.5e-4.pt" --steps 700 --crop 0 0 --learning-rate 2.5e-4 --pixel-loss-weight 200 $RESTORER_OPTIONS
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S9/from10400_px200_700.pt" dd2_mask="$S9/from11100_px1000_600.pt" \
  dd2_mask="$S9/from11100_px200_700_lr2.5e-4.pt" --jobs 2 | tee "$S9/gate_table.txt"
python benchmarks/restorer_variants.py --restorer "$S9/from10400_px200_700.pt" --pairs "$DEV/pairs-heldout" \
  --stages-per-run 2 --seeds 4 --gains 0.8 1.2 1.4 | tee "$S9/variants.txt"

# Session 10 (docs/restorer.md, "Results (session 10)"): weight averaging (--ema-decay) against the
# same job without it, at 1000 whole-latent steps (seeds 0 and 1) and continued to 4000; a second pass trained on
# the first pass's outputs (benchmarks/restored_pairs.py).
S10=$DEV/s10
mkdir -p "$S10"
# The whole-latent dd2_mask set-up; sessions 16-17 add their own --world-model to WHOLE_SETUP.
WHOLE_SETUP="--arch dd2_mask --crop 0 0 $RESTORER_OPTIONS"
WHOLE="$WHOLE_SETUP --world-model $WM/wm_dd2.pt"
run "$S10/base_1000.pt" "$S10/base_1000.log" $RC train-restorer $WHOLE --pairs $PAIRS --out "$S10/base_1000.pt" --steps 1000
run "$S10/ema995_1000.pt" "$S10/ema995_1000.log" $RC train-restorer $WHOLE --pairs $PAIRS --out "$S10/ema995_1000.pt" \
  --steps 1000 --ema-decay 0.995
run "$S10/base_1000_seed1.pt" "$S10/base_1000_seed1.log" $RC train-restorer $WHOLE --pairs $PAIRS --out "$S10/base_1000_seed1.pt" \
  --steps 1000 --seed 1
run "$S10/ema995_1000_seed1.pt" "$S10/ema995_1000_seed1.log" $RC train-restorer $WHOLE --pairs $PAIRS --out "$S10/ema995_1000_seed1.pt" \
  --steps 1000 --seed 1 --ema-decay 0.995
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S10/base_1000.pt" dd2_mask="$S10/ema995_1000.pt" \
  dd2_mask="$S10/base_1000_seed1.pt" dd2_mask="$S10/ema995_1000_seed1.pt" --jobs 2 | tee "$S10/gate_ema_1000.txt"
run "$S10/base_from1000_3000.pt" "$S10/base_from1000_3000.log" $RC train-restorer $WHOLE --pairs $PAIRS \
  --init-restorer "$S10/base_1000.pt" --out "$S10/base_from1000_3000.pt" --steps 3000
run "$S10/ema_from1000_3000.pt" "$S10/ema_from1000_3000.log" $RC train-restorer $WHOLE --pairs $PAIRS \
  --init-restorer "$S10/ema995_1000.pt" --out "$S10/ema_from1000_3000.pt" --steps 3000 --ema-decay 0.999
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S10/base_from1000_3000.pt" dd2_mask="$S10/ema_from1000_3000.pt" --jobs 2 | tee "$S10/gate_ema_4000.txt"
# Second pass: pairs whose degraded clips are the 1000-step EMA restorer's outputs, a restorer trained
# on them the same way, scored on the restored held-out pairs (its gain adds to the first pass's).
python benchmarks/restored_pairs.py --restorer "$S10/ema995_1000.pt" --pairs "$DEV/pairs-heldout" --out "$S10/pairs-heldout-R1"
python benchmarks/restored_pairs.py --restorer "$S10/ema995_1000.pt" --pairs "$DEV/pairs-train" --out "$S10/pairs-train-R1"
run "$S10/R2_ema995_1000.pt" "$S10/R2_ema995_1000.log" $RC train-restorer $WHOLE --pairs "$S10/pairs-train-R1" \
  --out "$S10/R2_ema995_1000.pt" --steps 1000 --ema-decay 0.995
python benchmarks/restorer.py --pairs "$S10/pairs-heldout-R1" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S10/R2_ema995_1000.pt" | tee "$S10/gate_R2.txt"
# Session 11 (docs/restorer.md, "Results (session 11)"): how much of the gain is specific to the
# training scenes (--training-scenes), then 45 more training scenes (corpus-013..019, 023..060:
# street runs and pairs as above) against the same 2500 steps on the 13 scenes, both from the
# 4000-step EMA restorer of session 10 (the 45 scenes' street runs and pairs are made at the top).
S11=$DEV/s11
mkdir -p "$S11" "$S11/pairs-seen" "$S11/pairs-unseen"
ln -sfn "$PWD/$DEV"/pairs-train/corpus-00[39]__*.npz "$S11/pairs-seen/"
ln -sfn "$PWD/$DEV"/pairs-train/corpus-01[34]__*.npz "$S11/pairs-unseen/"
for restorer in "$S10/ema995_1000.pt" "$S10/ema_from1000_3000.pt"; do
  python benchmarks/restorer.py --pairs "$S11/pairs-unseen" --stages-per-run 2 --steps 1 --restorer dd2_mask="$restorer"
  python benchmarks/restorer.py --pairs "$S11/pairs-seen" --stages-per-run 2 --steps 1 --training-scenes --restorer dd2_mask="$restorer"
done | tee "$S11/gap.txt"
PAIRS58=$(for scene in $TRAIN_SCENES $MORE_SCENES; do ls "$DEV/pairs-train/${scene}"__*.npz; done)
run "$S11/scenes13_from4000_2500.pt" "$S11/scenes13_from4000_2500.log" $RC train-restorer $WHOLE --pairs $PAIRS \
  --init-restorer "$S10/ema_from1000_3000.pt" --out "$S11/scenes13_from4000_2500.pt" --steps 2500 --ema-decay 0.999
run "$S11/scenes58_from4000_2500.pt" "$S11/scenes58_from4000_2500.log" $RC train-restorer $WHOLE --pairs $PAIRS58 \
  --init-restorer "$S10/ema_from1000_3000.pt" --out "$S11/scenes58_from4000_2500.pt" --steps 2500 --ema-decay 0.999
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S11/scenes13_from4000_2500.pt" dd2_mask="$S11/scenes58_from4000_2500.pt" --jobs 2 | tee "$S11/gate_scenes.txt"
# The 58-scene restorer, 1500 more steps (two threads, the machine to itself).
run "$S11/scenes58_from6500_1500.pt" "$S11/scenes58_from6500_1500.log" $RC train-restorer $WHOLE --threads 2 \
  --pairs $PAIRS58 --init-restorer "$S11/scenes58_from4000_2500.pt" --out "$S11/scenes58_from6500_1500.pt" --steps 1500 --ema-decay 0.997
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S11/scenes58_from6500_1500.pt" --threads 2 | tee "$S11/gate_scenes58_8000.txt"
# Session 13 (docs/restorer.md, "Results (session 13)"): many more training scenes (corpus-000..019,
# 023..200: 198 scenes, street runs and pairs as above, their latents primed once), a second held-out
# set (corpus-201..206, never trained on), and one dd2_mask restorer trained from the world model on a
# growing set of scenes in stages (each stage starts from the last one's weights, --init-restorer):
# the session made the scenes while the restorer trained, and each stage took the scenes made by then.
S13=$DEV/s13
mkdir -p "$S13" "$DEV/pairs-heldout2"
scenes() { for i in "$@"; do printf "corpus-%03d\n" "$i"; done; }
for scene in $(seq -f "corpus-%03g" 61 200) $(seq -f "corpus-%03g" 201 206); do
  dest=pairs-train; [[ $scene > corpus-200 ]] && dest=pairs-heldout2
  run "results/corpus/$scene" "$DEV/logs/synth_$scene.log" $RC synth --seed $((10000 + 10#${scene#corpus-})) --preset default \
    --scene-id "$scene" --out "results/corpus/$scene"
  run "$DEV/recon/$scene/street/model.pt" "$DEV/logs/recon_$scene.log" $RC train-recon --scene "results/corpus/$scene" \
    --model street --preset default --seed 0 --threads 1 --out "$DEV/recon/$scene/street"
  run "$DEV/$dest/${scene}__street.npz" "$DEV/logs/pairs_$scene.log" $RC make-pairs --run "$DEV/recon/$scene/street" \
    --out "$DEV/$dest" --stages 4 --trajectories $TRAJECTORIES --threads 1
done
pairs_of() { for scene in "$@"; do ls "$DEV/pairs-train/${scene}"__*.npz; done; }
score() {  # score DIR NAME: gate table of DIR/NAME.pt on both held-out sets
  python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
    --restorer dd2_mask="$1/$2.pt" --threads 1 | tee "$1/gate_$2.txt"
  python benchmarks/restorer.py --pairs "$DEV/pairs-heldout2" --stages-per-run 2 --steps 1 \
    --restorer dd2_mask="$1/$2.pt" --threads 1 | tee "$1/heldout2_$2.txt"
}
STAGE1=$(pairs_of $(scenes $(seq 0 19) $(seq 23 39) $(seq 177 200)))   # 61 scenes
run "$S13/stage1_3000.pt" "$S13/stage1_3000.log" $RC train-restorer $WHOLE --pairs $STAGE1 \
  --out "$S13/stage1_3000.pt" --steps 3000 --ema-decay 0.998
score "$S13" stage1_3000
# 105 scenes and the first file of corpus-084 (its other three were still being rendered)
STAGE2="$(pairs_of $(scenes $(seq 0 19) $(seq 23 83) $(seq 177 200))) $DEV/pairs-train/corpus-084__street.npz"
run "$S13/stage2_4000.pt" "$S13/stage2_4000.log" $RC train-restorer $WHOLE --pairs $STAGE2 \
  --init-restorer "$S13/stage1_3000.pt" --out "$S13/stage2_4000.pt" --steps 4000 --ema-decay 0.999
score "$S13" stage2_4000
# Depth A/B from stage 2 on the same 151 scenes, same seed and steps: the restorer as it is (1 residual
# block per level) against one grown to 3 blocks per level (--blocks-per-level 3, added blocks start as
# the identity).
STAGE3=$(pairs_of $(scenes $(seq 0 19) $(seq 23 129) $(seq 177 200)))   # 151 scenes
for blocks in 1 3; do
  name=stage3_3000; [ "$blocks" = 1 ] || name=stage3_blocks${blocks}_3000
  run "$S13/$name.pt" "$S13/$name.log" $RC train-restorer $WHOLE --pairs $STAGE3 --blocks-per-level $blocks \
    --init-restorer "$S13/stage2_4000.pt" --out "$S13/$name.pt" --steps 3000 --ema-decay 0.998
  score "$S13" $name
done
# Stage 4: 5000 more steps from the 1-block stage 3 on all 157 scenes' pairs.
STAGE4=$(pairs_of $(scenes $(seq 0 19) $(seq 23 135) $(seq 177 200)))   # 157 scenes
run "$S13/stage4_5000.pt" "$S13/stage4_5000.log" $RC train-restorer $WHOLE --pairs $STAGE4 \
  --init-restorer "$S13/stage3_3000.pt" --out "$S13/stage4_5000.pt" --steps 5000 --ema-decay 0.999
score "$S13" stage4_5000

# Session 15 (docs/restorer.md, "Results (session 15)"): the baseline of the start-noise probes, a
# 1000-step whole-latent dd2_mask restorer on the 13 scenes' pairs, plain and averaged over seeds.
# (The two zero-start probes were not kept in the code: they did not help.)
S15=$DEV/s15
mkdir -p "$S15"
run "$S15/baseline_1000.pt" "$S15/baseline_1000.log" $RC train-restorer --arch dd2_mask --world-model "$WM/wm_dd2.pt" \
  --pairs $PAIRS --out "$S15/baseline_1000.pt" --steps 1000 --crop 0 0 --ema-decay 0.995 $RESTORER_OPTIONS
python benchmarks/restorer.py --pairs "$DEV/pairs-heldout" --stages-per-run 2 --steps 1 \
  --restorer dd2_mask="$S15/baseline_1000.pt" | tee "$S15/gate_baseline_1000.txt"
python benchmarks/restorer_variants.py --restorer "$S15/baseline_1000.pt" --pairs "$DEV/pairs-heldout" \
  --stages-per-run 2 --seeds 4 --gains 0.8 | tee "$S15/variants_baseline_1000.txt"

# Session 16 (docs/restorer.md, "Results (session 16)"): how much the world model's pretraining is
# worth to the restorer: dd2 world models pretrained 1 and 3000 steps (against long/'s 1000), each
# fine-tuned into a dd2_mask restorer exactly as session 15's baseline (1000 whole-latent steps,
# EMA 0.995, seed 0), scored on both held-out sets. (The session's per-clip log-loss A/B needs the
# reverted option: git checkout afad542.)
S16=$DEV/s16wm
mkdir -p "$S16"
for steps in 1 3000; do
  run "$S16/wm_dd2_$steps.pt" "$S16/wm_dd2_$steps.log" $RC pretrain-world-model --arch dd2 --corpus "$DEV/corpus-train" \
    --autoencoder "$AE" --out "$S16/wm_dd2_$steps.pt" --steps $steps --threads 1
  run "$S16/restorer_wm$steps.pt" "$S16/restorer_wm$steps.log" $RC train-restorer $WHOLE_SETUP --world-model "$S16/wm_dd2_$steps.pt" \
    --pairs $PAIRS --out "$S16/restorer_wm$steps.pt" --steps 1000 --ema-decay 0.995 --seed 0
  score "$S16" restorer_wm$steps
done

# Session 17 (docs/restorer.md, "Results (session 17)"): a dd2 world model pretrained 10000 steps,
# fine-tuned as session 16's (1000 whole-latent steps, EMA 0.995, seeds 0 and 1); the 3000- and
# 10000-step world models' restorers trained 2000 steps further (EMA 0.998, as session 16's
# 1000-step world model's); and the 3000-step world model's 3000-step restorer 5000 steps further
# on the pairs of 22 scenes (corpus-000..019, 023, 024; EMA 0.999), then 2000 more with two threads.
S17=$DEV/s17
mkdir -p "$S17"
run "$S17/wm_dd2_10000.pt" "$S17/wm_dd2_10000.log" $RC pretrain-world-model --arch dd2 --corpus "$DEV/corpus-train" \
  --autoencoder "$AE" --out "$S17/wm_dd2_10000.pt" --steps 10000 --threads 1
for seed in 0 1; do
  run "$S17/wm10000_1000_seed$seed.pt" "$S17/wm10000_1000_seed$seed.log" $RC train-restorer $WHOLE_SETUP \
    --world-model "$S17/wm_dd2_10000.pt" --pairs $PAIRS --out "$S17/wm10000_1000_seed$seed.pt" \
    --steps 1000 --ema-decay 0.995 --seed $seed
  score "$S17" wm10000_1000_seed$seed
done
run "$S17/wm3000_from1000_2000.pt" "$S17/wm3000_from1000_2000.log" $RC train-restorer $WHOLE_SETUP \
  --world-model "$S16/wm_dd2_3000.pt" --pairs $PAIRS --init-restorer "$S16/restorer_wm3000.pt" \
  --out "$S17/wm3000_from1000_2000.pt" --steps 2000 --ema-decay 0.998 --seed 0
score "$S17" wm3000_from1000_2000
run "$S17/wm10000_from1000_2000.pt" "$S17/wm10000_from1000_2000.log" $RC train-restorer $WHOLE_SETUP \
  --world-model "$S17/wm_dd2_10000.pt" --pairs $PAIRS --init-restorer "$S17/wm10000_1000_seed0.pt" \
  --out "$S17/wm10000_from1000_2000.pt" --steps 2000 --ema-decay 0.998 --seed 0
score "$S17" wm10000_from1000_2000
PAIRS22=$(pairs_of $(scenes $(seq 0 19) 23 24))
run "$S17/wm3000_22sc_from3000_5000.pt" "$S17/wm3000_22sc_from3000_5000.log" $RC train-restorer $WHOLE_SETUP \
  --world-model "$S16/wm_dd2_3000.pt" --pairs $PAIRS22 --init-restorer "$S17/wm3000_from1000_2000.pt" \
  --out "$S17/wm3000_22sc_from3000_5000.pt" --steps 5000 --ema-decay 0.999 --seed 0
score "$S17" wm3000_22sc_from3000_5000
run "$S17/wm3000_22sc_from8000_2000.pt" "$S17/wm3000_22sc_from8000_2000.log" $RC train-restorer $WHOLE_SETUP \
  --world-model "$S16/wm_dd2_3000.pt" --threads 2 --pairs $PAIRS22 \
  --init-restorer "$S17/wm3000_22sc_from3000_5000.pt" --out "$S17/wm3000_22sc_from8000_2000.pt" --steps 2000 --ema-decay 0.999 --seed 0
score "$S17" wm3000_22sc_from8000_2000

# Session 18 (docs/restorer.md, "Results (session 18)"): the pixel refiner (train-refiner). A
# dd2_mask restorer trained 3000 whole-latent steps from the world model on the 13 scenes' pairs
# (EMA 0.998); refiners trained on its outputs for the pairs of its own 13 scenes, of 15 scenes it
# never saw (corpus-013..019, 023..030), and of all 28 (6000 steps); and the refiner's network
# alone, without restorer (benchmarks/pixel_baseline.py), on the 13 scenes' pairs.
S18=$DEV/s18
mkdir -p "$S18"
BEFORE_S22=--no-output-norm  # the refiners of sessions 18-21 had no norm before their last conv
run "$S18/r3000.pt" "$S18/r3000.log" $RC train-restorer $WHOLE --pairs $PAIRS --out "$S18/r3000.pt" \
  --steps 3000 --ema-decay 0.998 --seed 0
UNSEEN15=$(pairs_of $(scenes $(seq 13 19) $(seq 23 30)))
run "$S18/r3000_ref13.pt" "$S18/r3000_ref13.log" $RC train-refiner --restorer "$S18/r3000.pt" --pairs $PAIRS \
  --out "$S18/r3000_ref13.pt" --steps 3000 --learning-rate 1e-3 --threads 1 $BEFORE_S22
run "$S18/r3000_ref15unseen.pt" "$S18/r3000_ref15unseen.log" $RC train-refiner --restorer "$S18/r3000.pt" --pairs $UNSEEN15 \
  --out "$S18/r3000_ref15unseen.pt" --steps 3000 --learning-rate 1e-3 --threads 1 $BEFORE_S22
# All 28 scenes, 6000 steps: at learning rate 1e-3 the job diverged (loss spike at step 1200, then the
# identity); at 5e-4, now the command's default, it trained.
for lr in 1e-3 5e-4; do
  name=r3000_ref28_6000; [ "$lr" = 1e-3 ] || name=r3000_ref28_6000_lr$lr
  run "$S18/$name.pt" "$S18/$name.log" $RC train-refiner --restorer "$S18/r3000.pt" --pairs $PAIRS $UNSEEN15 \
    --out "$S18/$name.pt" --steps 6000 --learning-rate $lr --threads 1 $BEFORE_S22
done
for name in r3000_ref13 r3000_ref15unseen r3000_ref28_6000 r3000_ref28_6000_lr5e-4; do score "$S18" $name; done
run "$S18/pixel_baseline_13sc.pt" "$S18/pixel_baseline_13sc.log" python benchmarks/pixel_baseline.py --pairs $PAIRS \
  --heldout "$DEV/pairs-heldout" --steps 3000 --learning-rate 1e-3 --out "$S18/pixel_baseline_13sc.pt" $BEFORE_S22

# Session 19 (docs/restorer.md, "Results (session 19)"): does the pixel refiner gain from seeing
# the frames around each one (--temporal-neighbours)? A dd2_mask restorer trained 2000 whole-latent
# steps from the world model on the 13 scenes' pairs (EMA 0.998), then two refiners on its outputs
# for the pairs of UNSEEN19 (scenes it never saw), the same in all but the neighbours: per frame
# (the session-18 refiner) and two frames before and after.
S19=$DEV/s19
mkdir -p "$S19"
run "$S19/r2000.pt" "$S19/r2000.log" $RC train-restorer $WHOLE --pairs $PAIRS --out "$S19/r2000.pt" \
  --steps 2000 --ema-decay 0.998 --seed 0
UNSEEN19=$(pairs_of $(scenes $(seq 13 19) $(seq 23 36)))
for neighbours in 0 2; do
  run "$S19/r2000_ref_n$neighbours.pt" "$S19/r2000_ref_n$neighbours.log" $RC train-refiner --restorer "$S19/r2000.pt" \
    --pairs $UNSEEN19 --out "$S19/r2000_ref_n$neighbours.pt" --steps 5000 --temporal-neighbours $neighbours --threads 1 $BEFORE_S22
  score "$S19" r2000_ref_n$neighbours
done
# The same two refiners with seed 1, scored on heldout2 only (the session's time ran short).
for neighbours in 0 2; do
  run "$S19/r2000_ref_n${neighbours}_seed1.pt" "$S19/r2000_ref_n${neighbours}_seed1.log" $RC train-refiner --restorer "$S19/r2000.pt" \
    --pairs $UNSEEN19 --out "$S19/r2000_ref_n${neighbours}_seed1.pt" --steps 5000 --temporal-neighbours $neighbours --seed 1 --threads 1 $BEFORE_S22
  python benchmarks/restorer.py --pairs "$DEV/pairs-heldout2" --stages-per-run 2 --steps 1 \
    --restorer dd2_mask="$S19/r2000_ref_n${neighbours}_seed1.pt" --threads 1 | tee "$S19/heldout2_r2000_ref_n${neighbours}_seed1.txt"
done

# Session 21 (docs/restorer.md, "Results (session 21)"): session 13's staged training on a short
# budget: a dd2_mask restorer 1500 whole-latent steps from the world model on the 16 scenes made
# first, then 1000 steps more on the 35 made by then (corpus-000..019, 023..037); a refiner with
# two neighbours each side on its outputs for 12 of its own scenes and 12 it never saw
# (corpus-038..049). (The 4-frame window overlap of the results was a scratch probe, not scripted.)
S21=$DEV/s21
mkdir -p "$S21"
run "$S21/stage1.pt" "$S21/stage1.log" $RC train-restorer $WHOLE --pairs $(pairs_of $(scenes $(seq 0 15))) \
  --out "$S21/stage1.pt" --steps 1500 --ema-decay 0.998 --seed 0
run "$S21/stage2.pt" "$S21/stage2.log" $RC train-restorer $WHOLE --pairs $(pairs_of $(scenes $(seq 0 19) $(seq 23 37))) \
  --init-restorer "$S21/stage1.pt" --out "$S21/stage2.pt" --steps 1000 --ema-decay 0.997 --seed 0
run "$S21/stage2_ref.pt" "$S21/stage2_ref.log" $RC train-refiner --restorer "$S21/stage2.pt" \
  --pairs $(pairs_of $(scenes $(seq 0 11) $(seq 38 49))) --out "$S21/stage2_ref.pt" --steps 5000 --temporal-neighbours 2 --threads 1 \
  $BEFORE_S22
score "$S21" stage2_ref

# Session 22 (docs/restorer.md, "Results (session 22)"): session 21's refiner job again, now with the
# channel norm before its last conv; session 21's restorer 3500 steps further on all 47 training
# scenes made then (corpus-000..019, 023..049), and a refiner on its outputs for 12 of its scenes
# and 12 it never saw (corpus-050..061).
S22=$DEV/s22
mkdir -p "$S22"
run "$S22/stage2_ref_norm.pt" "$S22/stage2_ref_norm.log" $RC train-refiner --restorer "$S21/stage2.pt" \
  --pairs $(pairs_of $(scenes $(seq 0 11) $(seq 38 49))) --out "$S22/stage2_ref_norm.pt" --steps 5000 --temporal-neighbours 2 --threads 1
score "$S22" stage2_ref_norm
run "$S22/stage3.pt" "$S22/stage3.log" $RC train-restorer $WHOLE --pairs $(pairs_of $(scenes $(seq 0 19) $(seq 23 49))) \
  --init-restorer "$S21/stage2.pt" --out "$S22/stage3.pt" --steps 3500 --ema-decay 0.999 --seed 0
run "$S22/stage3_ref.pt" "$S22/stage3_ref.log" $RC train-refiner --restorer "$S22/stage3.pt" \
  --pairs $(pairs_of $(scenes $(seq 0 11) $(seq 50 61))) --out "$S22/stage3_ref.pt" --steps 5000 --temporal-neighbours 2 --threads 1
score "$S22" stage3_ref

# Session 23 (docs/restorer.md, "Results (session 23)"): session 22's restorer 3500 steps further on
# all 67 training scenes made by then (corpus-000..019, 023..069), scored with 1 and 4 noise draws
# averaged; a refiner on its 4-draw outputs for 12 of its scenes and 12 it never saw
# (corpus-071..082; the session-13 part above makes every scene up to corpus-200). The session's
# restorer job ran its first 400 steps as a 5000-step job, then resumed as a 3500-step one: the
# same batches, a slightly different learning-rate curve before step 400.
S23=$DEV/s23
mkdir -p "$S23"
run "$S23/stage4.pt" "$S23/stage4.log" $RC train-restorer $WHOLE --pairs $(pairs_of $(scenes $(seq 0 19) $(seq 23 69))) \
  --init-restorer "$S22/stage3.pt" --out "$S23/stage4.pt" --steps 3500 --ema-decay 0.999 --seed 0
for heldout in pairs-heldout pairs-heldout2; do
  python benchmarks/restorer.py --pairs "$DEV/$heldout" --stages-per-run 2 --steps 1 --samples 1 4 \
    --restorer dd2_mask="$S23/stage4.pt" --threads 1 | tee "$S23/${heldout}_stage4.txt"
done
run "$S23/stage4_ref.pt" "$S23/stage4_ref.log" $RC train-refiner --restorer "$S23/stage4.pt" --samples 4 \
  --pairs $(pairs_of $(scenes $(seq 0 11) $(seq 71 82))) --out "$S23/stage4_ref.pt" --steps 5000 --temporal-neighbours 2 --threads 1
score "$S23" stage4_ref

# Session 24 (docs/restorer.md, "Results (session 24)"): session 23's refiner with its correction
# clipped after the fact (benchmarks/refiner_bound.py), on 4 scenes made this session that no network
# trained on (corpus-095..098; the bound of 12 grey levels, RefinerConfig.max_correction's default,
# was chosen there) and on both held-out sets; session 23's restorer 3500 steps further on all 79
# training scenes made by then (corpus-000..019, 023..082); a refiner with the default bound on its
# 4-draw outputs for 12 of its scenes and 12 it never saw (corpus-083..094). (The restorer's
# --samples 4 overrides RESTORER_OPTIONS' 1: it stores 4 draws, as train-restorer now does by default.)
S24=$DEV/s24
mkdir -p "$S24"
python benchmarks/refiner_bound.py --restorer "$S23/stage4_ref.pt" --pairs "$DEV"/pairs-train/corpus-09[5-8]__street*.npz \
  | tee "$S24/bound_stage4_ref_val.txt"
for heldout in pairs-heldout pairs-heldout2; do
  python benchmarks/refiner_bound.py --restorer "$S23/stage4_ref.pt" --pairs "$DEV/$heldout" | tee "$S24/bound_stage4_ref_$heldout.txt"
done
run "$S24/stage5.pt" "$S24/stage5.log" $RC train-restorer $WHOLE --samples 4 --pairs $(pairs_of $(scenes $(seq 0 19) $(seq 23 82))) \
  --init-restorer "$S23/stage4.pt" --out "$S24/stage5.pt" --steps 3500 --ema-decay 0.999 --seed 0
for heldout in pairs-heldout pairs-heldout2; do
  python benchmarks/restorer.py --pairs "$DEV/$heldout" --stages-per-run 2 --steps 1 --samples 1 4 \
    --restorer dd2_mask="$S24/stage5.pt" --threads 1 | tee "$S24/${heldout}_stage5.txt"
done
run "$S24/stage5_ref.pt" "$S24/stage5_ref.log" $RC train-refiner --restorer "$S24/stage5.pt" --samples 4 --max-correction 12 \
  --pairs $(pairs_of $(scenes $(seq 0 11) $(seq 83 94))) --out "$S24/stage5_ref.pt" --steps 5000 --temporal-neighbours 2 --threads 1
score "$S24" stage5_ref
