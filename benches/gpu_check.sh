#!/bin/bash
# Issue 35's GPU figures in one run of about 10 minutes on one H100-class GPU
# (prints, asserts nothing): the full setting's projection, one NRI epoch at
# the paper's size (eager against CUDA graphs), NRI and NRI with trail
# messages against the path rule and Granger on the toy world at full size,
# and NRI on NRI's springs at NRI's data size.
#
#   PYTHON=python3 bash benches/gpu_check.sh
#
# Needs the causalcity package with the methods extra importable by $PYTHON
# (for a machine without a network: make wheel here, then
# pip install --no-deps --target /tmp/site target/wheels/*.whl and
# PYTHONPATH=/tmp/site there). Run from the repository root.
set -u
PYTHON=${PYTHON:-python3}
export PYTHONUNBUFFERED=1 BENCH_DEVICE=${BENCH_DEVICE:-cuda}
start=$(date +%s)
stage() { echo "== [$(( $(date +%s) - start )) s] $*"; }
stage "device"
$PYTHON -c "import torch, os; print(torch.__version__, torch.cuda.get_device_name() if torch.cuda.is_available() else 'no CUDA device', os.cpu_count(), 'cores')"
stage "the full setting's projection"
timeout 120 $PYTHON -m causalcity.paper --plan --device "$BENCH_DEVICE"
stage "one epoch at the paper's size, then NRI, NRI with trail messages, the path rule and Granger on the toy at full size"
BENCH_ONLY=epoch,toy BENCH_TOY_SECONDS=${TOY_SECONDS:-120} timeout 480 $PYTHON benches/nri_methods.py
stage "springs at NRI's size"
BENCH_ONLY=springs BENCH_SPRINGS_TRAIN=${SPRINGS_TRAIN:-50000} BENCH_SPRINGS_EPOCHS=500 BENCH_SPRINGS_SECONDS=${SPRINGS_SECONDS:-150} \
    timeout 300 $PYTHON benches/nri_methods.py
stage "done"
