#!/usr/bin/env bash
# ReconDreamer with a restorer trained outside the workflow (e.g. a weight set's), at the
# size of a finished run, without retraining anything else: the baseline runs, scenes and
# evaluation models of SOURCE are reused, and each ReconDreamer run is trained and evaluated with the
# commands that config/full.yaml's rules use. Metric files land in the workflow's layout under OUT,
# so the gate's report reads them. It measures what a better restorer changes in the methods gate's
# table; docs/methods.md cites it for that (Results with a better restorer):
#
#   experiments/restorer_in_loop.sh results/restorer-dev/s8/from9500_whole_px50_900.pt synth-01 synth-02 ...
#   python benchmarks/methods_gate.py --configfile config/full.yaml --results-dir results/restorer-in-loop \
#       --backbones street --methods baseline recondreamer --report-only
#
# Environment: SOURCE (results/full, a finished 'snakemake --configfile config/full.yaml' run),
# OUT (results/restorer-in-loop), BACKBONE (street), STRIDES ("1.5 6.0"), PRESET (default),
# RESTORER_NAME (dd2_mask: the run ids' restorer part, the config's main restorer), REFERENCE_RUNS
# (the runs of SOURCE compared against: "baseline-$BACKBONE"; add dd4d-pvg for DriveDreamer4D with PVG).
# The reference runs are evaluated again into OUT with the current code, so every row comes from the
# same evaluation. Finished metric files are kept: rerunning the script resumes where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 2 ]; then
  echo "usage: $0 RESTORER_CHECKPOINT SEGMENT..." >&2
  exit 2
fi
CKPT=$1; shift
SOURCE=${SOURCE:-results/full}
OUT=${OUT:-results/restorer-in-loop}
BACKBONE=${BACKBONE:-street}
STRIDES=${STRIDES:-1.5 6.0}
PRESET=${PRESET:-default}
RESTORER_NAME=${RESTORER_NAME:-dd2_mask}
REFERENCE_RUNS=${REFERENCE_RUNS:-baseline-$BACKBONE}
[ -f "$CKPT" ] || { echo "restorer checkpoint $CKPT: no such file" >&2; exit 2; }
for seg in "$@"; do
  for needed in "$SOURCE/scenes/$seg" "$SOURCE/eval_models" $(for run in $REFERENCE_RUNS; do echo "$SOURCE/runs/$seg/$run"; done); do
    [ -e "$needed" ] || { echo "$needed: missing; run the workflow with SOURCE's config first" >&2; exit 2; }
  done
done

evaluate() {  # SEGMENT RUN_DIR RUN_ID: render the three trajectories and score them, as the rule 'evaluate'
  local seg=$1 run=$2 name=$3 args=()
  for trajectory in shift@3 shift@6 lane_change; do
    args+=(--renders "$OUT/renders/$seg/$name/$trajectory" --trajectory "$trajectory")
  done
  recondreamer evaluate --scene "$SOURCE/scenes/$seg" --run "$run" "${args[@]}" --models "$SOURCE/eval_models" \
    --min-lidar-points 10 --score-threshold 0.5 --out "$OUT/metrics/$seg/$name.json" \
    --features-out "$OUT/metrics/$seg/$name.features.npz" --threads 1 > "$OUT/logs/$seg/$name.eval.log" 2>&1
}

for seg in "$@"; do
  mkdir -p "$OUT/logs/$seg" "$OUT/metrics/$seg"
  for run in $REFERENCE_RUNS; do
    [ -e "$OUT/metrics/$seg/$run.json" ] && continue
    evaluate "$seg" "$SOURCE/runs/$seg/$run" "$run"
    echo "$(date +%T) $seg: evaluated $run"
  done
  for stride in $STRIDES; do
    name=recondreamer-$BACKBONE-$RESTORER_NAME-stride$stride
    [ -e "$OUT/metrics/$seg/$name.json" ] && continue
    recondreamer train-recondreamer --scene "$SOURCE/scenes/$seg" --model "$BACKBONE" --restorer "$CKPT" --stride "$stride" \
      --out "$OUT/runs/$seg/$name" --preset "$PRESET" --seed 0 --backend auto --threads 1 > "$OUT/logs/$seg/$name.train.log" 2>&1
    evaluate "$seg" "$OUT/runs/$seg/$name" "$name"
    echo "$(date +%T) $seg: trained and evaluated $name"
  done
done
