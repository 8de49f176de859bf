#!/bin/bash
# Students for the chapter-7.3 tables (Table 14: five encodings at H = 10, dt = 0.02 s; Table 15: first-spline
# at the other (dt, H)); first-spline H = 10 dt = 0.02 is the committed docs/policies student.
# Resumable: a finished student is skipped, an interrupted one continues (--resume).
#   bash experiments/make_students.sh [table14|table15|all] [EPOCHS] [DATAPOINTS_PER_EPOCH]
# Defaults: all, 10 epochs x 10 000 datapoints (the distillation experiments' "medium" scale; Table 7 is 30 x 80 000).
set -u
cd "$(dirname "$0")/.."
which=${1:-all}; epochs=${2:-10}; points=${3:-10000}
out=${STUDENTS:-results/experiments/students}
specs=()
if [ "$which" = table14 ] || [ "$which" = all ]; then
  for enc in discrete-discrete discrete-spline spline-discrete spline-spline first-discrete; do specs+=("$enc 10 0.02"); done
fi
if [ "$which" = table15 ] || [ "$which" = all ]; then
  for hd in "5 0.02" "5 0.04" "15 0.02" "10 0.04" "15 0.04"; do specs+=("first-spline $hd"); done
fi
for spec in "${specs[@]}"; do
  set -- $spec
  dir=$out/$1_H$2_dt$3
  if [ -f "$dir/exported/student.pt2" ] || [ -f "$dir/exported/student.pt" ]; then echo "have $dir"; continue; fi
  resume=""; [ -f "$dir/checkpoint.pt" ] && resume="--resume"
  echo "=== $dir start $(date -u +%T)"
  OMP_NUM_THREADS=1 .venv/bin/python -m dls_quadruped.learning.distill --encoding "$1" --horizon "$2" --dt "$3" \
    --algo dagger --epochs "$epochs" --datapoints-per-epoch "$points" --num-envs 64 --test-datapoints 2000 \
    --sp-episodes 32 --sp-every 0 --run-dir "$dir" $resume
  echo "=== $dir end rc=$? $(date -u +%T)"
done
