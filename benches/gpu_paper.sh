#!/bin/bash
# The paper's full setting (4000/500/500 scenarios, 100 epochs) on one GPU
# for as many whole units as a time budget allows, one group at a time:
# NRI on the toy world, NRI on the city, then the interaction net on each,
# while a second process (at low priority) runs the methods without a
# network on the CPU's cores, PCMCI first. The finished (world, method,
# group) units and their predictions are tarred into $OUT/units.tar every
# 15 s, beside the logs; on the machine that keeps the results, unpack
# its gpu/ and cpu/ units and predictions into one DIR and rerun
# `python -m causalcity.paper --group GROUP --device cuda --out DIR` to run
# what is left and write the table. Prints progress, asserts nothing.
#
#   PYTHON=python3 OUT=results/paper-gpu bash benches/gpu_paper.sh
#
# Knobs: PAPER_SECONDS (the whole run's budget, default 540), PAPER_GROUP
# (cars08_edges50), PAPER_DEVICE (cuda), PAPER_FLAGS (extra flags for both
# processes, e.g. "--splits 20/5/5 --epochs 2" for a rehearsal on a CPU),
# WORK (the datasets' folder, default /tmp/paper-gpu). Needs the causalcity
# package with the methods extra importable by $PYTHON (for a machine
# without a network: make wheel here, then pip install --no-deps --target
# /tmp/site target/wheels/*.whl and PYTHONPATH=/tmp/site there). Run from
# the repository root.
set -u
PYTHON=${PYTHON:-python3}
OUT=${OUT:-results/paper-gpu}
BUDGET=${PAPER_SECONDS:-540}
GROUP=${PAPER_GROUP:-cars08_edges50}
DEVICE=${PAPER_DEVICE:-cuda}
WORK=${WORK:-/tmp/paper-gpu}
export PYTHONUNBUFFERED=1
start=$(date +%s)
left() { echo $(( BUDGET - ($(date +%s) - start) )); }
stage() { echo "== [$(( $(date +%s) - start )) s] $*"; }
mkdir -p "$OUT" "$WORK"
OUT=$(cd "$OUT" && pwd)

stage "device"
$PYTHON -c "import torch, os; print(torch.__version__, torch.cuda.get_device_name() if torch.cuda.is_available() else 'no CUDA device', os.cpu_count(), 'cores')"

paper() { # OUT-FOLDER WORLD METHOD...: one paper run, cut off when the budget ends
    local folder=$1 world=$2
    shift 2
    local t
    t=$(left)
    if [ "$t" -le 20 ]; then
        echo "no time left for $world $*"
        return 1
    fi
    # shellcheck disable=SC2086
    timeout --signal=INT --kill-after=10 "$t" $PYTHON -m causalcity.paper --device "$DEVICE" --world "$world" \
        --group "$GROUP" --method "$@" --out "$folder" ${PAPER_FLAGS:-}
}

copy_units() { # the finished units so far, so that a run cut off from outside still leaves them in $OUT
    # One tar, not folders: the device tool brings back files, but not from
    # folders nested as deep as units/WORLD/METHOD/.
    local parts=()
    for side in gpu cpu; do
        for kind in units predictions; do
            [ -d "$WORK/$side/$kind" ] && parts+=("$side/$kind")
        done
        [ -f "$WORK/$side/timings.json" ] && cp "$WORK/$side/timings.json" "$OUT/timings-$side.json"
    done
    [ ${#parts[@]} -gt 0 ] && tar -C "$WORK" -cf "$OUT/units.tar.partial" "${parts[@]}" 2>/dev/null &&
        mv "$OUT/units.tar.partial" "$OUT/units.tar"
    return 0
}
(while sleep 15; do copy_units; done) &
copier=$!

# The CPU's share, niced so that it never holds up the GPU's: PCMCI first,
# since it gains most from many cores (its numpy backend needs no tigramite).
cpu_methods="pcmci path frame0 granger constant_velocity supervised"
(
    for world in toy city; do
        # shellcheck disable=SC2086
        nice -n 19 bash -c "$(declare -f left paper); BUDGET=$BUDGET start=$start PYTHON='$PYTHON' DEVICE=cpu \
            GROUP=$GROUP PAPER_FLAGS='${PAPER_FLAGS:-}' paper '$WORK/cpu' $world $cpu_methods" || true
    done
) > "$OUT/cpu.log" 2>&1 &
cpu=$!

for unit in "toy nri" "city nri" "toy interaction" "city interaction"; do
    # shellcheck disable=SC2086
    set -- $unit
    stage "GPU: $1 $2"
    paper "$WORK/gpu" "$1" "$2" >> "$OUT/gpu.log" 2>&1 || tail -n 15 "$OUT/gpu.log"
    grep "^\[paper\]" "$OUT/gpu.log" | tail -n 3
done
stage "waiting for the CPU methods"
wait $cpu
grep "^\[paper\]\|rror" "$OUT/cpu.log" | tail -n 20
stage "copying the finished units"
kill $copier 2>/dev/null
wait $copier 2>/dev/null
copy_units
tar -tf "$OUT/units.tar" 2>/dev/null | grep "units/.*json$" | sort
stage "done"
