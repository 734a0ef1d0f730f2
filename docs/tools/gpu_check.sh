#!/usr/bin/env bash
# GPU readiness in one short run, from the repository root of a fresh clone on a machine with a GPU:
#
#   bash docs/tools/gpu_check.sh              # make venv if needed, colcon build, then every check on cuda
#   bash docs/tools/gpu_check.sh --device cpu # the same steps on the CPU: a dry run of the script without a GPU
#
# 1. No CUDA device visible: one line, exit 1, before anything is installed.
# 2. `make venv` (the pinned torch==2.13.0 resolves to PyPI's CUDA build where no CPU wheel is offered first;
#    docs/CHOOSING.md, "Installing and testing") and torch must see the GPU.
# 3. colcon build into out/ws, as `make demo` does (the node runs from its install).
# 4. docs/tools/gpu_check.py compare: NormalEstimator on cuda against the CPU at the same query points of a
#    simulated depth frame (pca through the integral-image window, the KD-tree and the cell lists; learned and
#    hybrid through the KD-tree, the cell lists and the GPU's default grid), then full frames of pca, learned and
#    hybrid timed on cuda. No test in test/ runs on CUDA, so these comparisons stand in for GPU tests.
# 5. `triplet-normal bench --device cuda`, its tables into out/gpu_check/bench.md (docs/RESULTS.md is not touched).
# 6. The installed node on cuda (its default method, hybrid) on the shipped real 640x480 frame.
# Then one markdown table (what, device, seconds, result, ok); the exit status is 1 when any row failed.
# Logs and outputs: out/gpu_check/. About 5 minutes after the venv exists on a GPU machine.
set -uo pipefail

DEVICE=cuda
if [[ ${1:-} == --device ]]; then
    DEVICE=${2:?--device needs a value: cuda, cuda:N or cpu}
elif [[ $# -gt 0 ]]; then
    echo "usage: bash docs/tools/gpu_check.sh [--device cuda|cuda:N|cpu]" >&2
    exit 2
fi
cd "$(dirname "${BASH_SOURCE[0]}")/../.." || exit 1

if [[ $DEVICE != cpu ]]; then
    if ! nvidia-smi -L 2>/dev/null | grep -q '^GPU ' && ! compgen -G '/dev/nvidia[0-9]*' >/dev/null; then
        echo "gpu_check: no CUDA device visible (nvidia-smi lists none and there is no /dev/nvidia*); nothing checked" >&2
        exit 1
    fi
fi

OUT=out/gpu_check
mkdir -p "$OUT"
RESULTS=$OUT/results.jsonl
: >"$RESULTS"
PY=.venv/bin/python
HELPER=docs/tools/gpu_check.py
WS=out/ws

echo "gpu_check: make venv (log: $OUT/venv.log)" >&2
if ! make venv >"$OUT/venv.log" 2>&1; then
    echo "gpu_check: make venv failed; see $OUT/venv.log" >&2
    exit 1
fi
if ! "$PY" "$HELPER" probe --device "$DEVICE" >"$OUT/probe.txt"; then
    exit 1
fi
echo "gpu_check: $(cat "$OUT/probe.txt")" >&2

# now() and seconds since a start, with date and awk.
now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

echo "gpu_check: colcon build into $WS (log: $OUT/colcon.log)" >&2
start=$(now)
if .venv/bin/colcon --log-base "$WS/log" build --base-paths . --build-base "$WS/build" --install-base "$WS/install" \
    --event-handlers console_direct- console_start_end- >"$OUT/colcon.log" 2>&1; then
    "$PY" "$HELPER" record --results "$RESULTS" --device "$DEVICE" --what "colcon build" --seconds "$(since "$start")" \
        --result "installed into $WS/install" --ok yes
else
    "$PY" "$HELPER" record --results "$RESULTS" --device "$DEVICE" --what "colcon build" --seconds "$(since "$start")" \
        --result "failed; see $OUT/colcon.log" --ok no
fi

echo "gpu_check: estimator on $DEVICE against the CPU (log: $OUT/compare.log)" >&2
if ! "$PY" "$HELPER" compare --results "$RESULTS" --device "$DEVICE" 2>"$OUT/compare.log"; then
    "$PY" "$HELPER" record --results "$RESULTS" --device "$DEVICE" --what "compare" \
        --result "crashed; see $OUT/compare.log: $(tail -n 1 "$OUT/compare.log")" --ok no
fi

echo "gpu_check: triplet-normal bench --device $DEVICE (log: $OUT/bench.log)" >&2
rm -f "$OUT/bench.md"
start=$(now)
.venv/bin/triplet-normal bench --device "$DEVICE" --out "$OUT/bench.md" >"$OUT/bench.log" 2>&1
rc=$?
"$PY" "$HELPER" bench-row --results "$RESULTS" --device "$DEVICE" --markdown "$OUT/bench.md" --rc "$rc" \
    --seconds "$(since "$start")" --log "$OUT/bench.log"

echo "gpu_check: the installed node on $DEVICE, full frames (log: $OUT/node.log)" >&2
if ! "$PY" "$HELPER" node --results "$RESULTS" --device "$DEVICE" --prefix "$WS/install/triplet_normal_ros" \
    --out "$OUT" 2>"$OUT/node_client.log"; then
    "$PY" "$HELPER" record --results "$RESULTS" --device "$DEVICE" --what "node" \
        --result "crashed; see $OUT/node_client.log: $(tail -n 1 "$OUT/node_client.log")" --ok no
fi

echo
echo "GPU check: $(cat "$OUT/probe.txt") · $(date -u +%Y-%m-%d) · $(git rev-parse --short HEAD 2>/dev/null || echo 'no git')"
echo
"$PY" "$HELPER" table --results "$RESULTS"
