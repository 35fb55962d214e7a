#!/usr/bin/env bash
# The estimator's gate: a change of it judged on everything the issues' acceptance reads, in one command.
#
#   bench/estimator_gate.sh TAG [BASE_TAG] [name=value ...]
#
# Runs, each as two shards side by side (the machine's two cores), with the estimator's tunables set by the
# name=value arguments: the robustness sweep against today's path (estimator_sweep.py --against), the two maps over
# seeds and strengths (map_seeds.py) and the clean runs over seeds (steady_maps.py). Every output is kept in
# $GATE_DIR/TAG/ (default $TMPDIR/graytrack-gate); each bench keeps its cases in its own cache, so after the first
# run (tens of minutes: every case rendered and today's path scored) a gate costs the tracking only (a few minutes).
# The totals of each bench are printed, and with BASE_TAG every sweep run that moved (bench/sweep_diff.py).
# LEVEL_SCALE=0.99 (env) holds every frame against a calibration level 1 % off: which runs move on chance alone.
# SENSITIVITY=1 (env) also runs tunable_sensitivity.py read and without the grating (a few minutes more): the runs
# whose figures turn several-fold, or lose their flags, when one rate is set 1.5x off.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
python="$here/../.venv/bin/python"
tag="${1:?usage: estimator_gate.sh TAG [BASE_TAG] [name=value ...]}"
shift
base=""
if [[ $# -gt 0 && "$1" != *=* ]]; then
    base="$1"
    shift
fi
root="${GATE_DIR:-${TMPDIR:-/tmp}/graytrack-gate}"
out="$root/$tag"
mkdir -p "$out"
scale=(--level-scale "${LEVEL_SCALE:-1}")
cd "$here"
for bench in estimator_sweep map_seeds steady_maps; do
    extra=()
    [[ $bench == estimator_sweep ]] && extra=(--against)
    for shard in 0 1; do
        "$python" "$bench.py" "${extra[@]}" "${scale[@]}" --shard "$shard/2" "$@" > "$out/$bench.$shard.txt" 2>&1 &
    done
    wait
done
if [[ "${SENSITIVITY:-0}" == 1 ]]; then
    for shard in 0 1; do
        "$python" tunable_sensitivity.py --modes=grating,--no-reference --shard "$shard/2" "$@" \
            > "$out/tunable_sensitivity.$shard.txt" 2>&1 &
    done
    wait
fi
for bench in estimator_sweep map_seeds steady_maps; do
    echo "== $bench ($tag)"
    grep -h '^total\|^against\|^steady: [0-9]' "$out/$bench".*.txt || true
done
if [[ "${SENSITIVITY:-0}" == 1 ]]; then
    echo "== tunable_sensitivity ($tag)"
    grep -h ' edge$\|^total' "$out"/tunable_sensitivity.*.txt || true
fi
if [[ -n "$base" ]]; then
    "$python" sweep_diff.py "$root/$base/estimator_sweep.0.txt,$root/$base/estimator_sweep.1.txt" \
        "$out/estimator_sweep.0.txt,$out/estimator_sweep.1.txt"
fi
