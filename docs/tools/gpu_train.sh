#!/usr/bin/env bash
# A lent GPU's whole session in one call, within a fixed time: the estimator on cuda against the CPU
# (gpu_check.py probe and compare), bounded to a fifth of the budget, then one training run in the time left, stopped cleanly before it runs out.
#
#   bash docs/tools/gpu_train.sh BUDGET_S OUT_DIR [triplet-normal train options...]
#   bash docs/tools/gpu_train.sh 60 out/gpu_dry --device cpu --recipe range --shapes sphere --val-shapes sphere
#
# For a machine with torch, numpy, scipy, numba and tqdm but no network and no ROS (the device image): trimesh,
# manifold3d and rtree, which the training shapes need, are installed from .whl/ when they are missing
# (pip download ... -d .whl, python 3.12 wheels). No venv and no colcon build: the node's GPU check is
# docs/tools/gpu_check.sh, which needs ROS's wheels.
#
# Training writes state.pt after every epoch; when the budget runs out the run gets SIGINT, and state.pt resumes it
# anywhere (`triplet-normal train --resume` with the same options and --run-dir; a GPU state resumes on a CPU).
# OUT_DIR receives: check.md (the comparison table), compare.log, train.log, history.json, state.pt,
# model.safetensors (when the schedule finished) and training_curves.png.
set -uo pipefail
BUDGET=${1:?budget in seconds}
OUT_DIR=${2:?output folder}
shift 2
DEVICE=cuda
for ((i = 1; i <= $#; i++)); do
    [[ ${!i} == --device ]] && j=$((i + 1)) && DEVICE=${!j}
done
cd "$(dirname "${BASH_SOURCE[0]}")/../.." || exit 1
start=$(date +%s)
left() { echo $((BUDGET - ($(date +%s) - start))); }
mkdir -p "$OUT_DIR"
PY=${PYTHON:-python3}
if ! "$PY" -c 'import trimesh, manifold3d, rtree' 2>/dev/null && compgen -G '.whl/*.whl' >/dev/null; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/gpu_train_site \
        .whl/*.whl || exit 1
    export PYTHONPATH=/tmp/gpu_train_site${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1

RESULTS=/tmp/gpu_train_results.jsonl
: >"$RESULTS"
if "$PY" docs/tools/gpu_check.py probe --device "$DEVICE"; then
    timeout $((BUDGET / 5)) "$PY" docs/tools/gpu_check.py compare --results "$RESULTS" --device "$DEVICE" \
        2>"$OUT_DIR/compare.log" || echo "gpu_train: compare stopped or failed; see compare.log"
    "$PY" docs/tools/gpu_check.py table --results "$RESULTS" >"$OUT_DIR/check.md"
    cat "$OUT_DIR/check.md"
fi

RUN=/tmp/gpu_train_run
mkdir -p "$RUN"
[[ -f $OUT_DIR/state.pt ]] && cp "$OUT_DIR/state.pt" "$RUN/"
limit=$(($(left) - 20))
echo "gpu_train: training for at most ${limit} s: $*"
timeout -s INT -k 15 "$limit" "$PY" -c \
    'import sys; from triplet_normal_ros.cli.main import main; sys.exit(main())' train --run-dir "$RUN" "$@" \
    >"$OUT_DIR/train.log" 2>&1
echo "gpu_train: train exited $? after $(($(date +%s) - start)) s"
tail -n 5 "$OUT_DIR/train.log"
for f in state.pt history.json model.safetensors training_curves.png; do
    [[ -f $RUN/$f ]] && cp "$RUN/$f" "$OUT_DIR/"
done
ls -la "$OUT_DIR"
