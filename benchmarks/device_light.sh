#!/usr/bin/env bash
# Issue 16 item 4 on a lent GPU: the device tool's `run` with
#   command "bash benchmarks/device_light.sh", carry ["device/wheels", "device/geometry.npz"]
# after `python benchmarks/device_light.py prepare` here (see that script's docstring).
# The results come back as $OUT/device_light.json and $OUT/device_light.log.
set -o pipefail
OUT=${OUT:-benchmarks/results}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    device/wheels/*.whl || exit 1
# JAX is only imported (lightfit's float64 policy) and must not take the GPU's memory from Dr.Jit.
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 JAX_PLATFORMS=cpu XLA_PYTHON_CLIENT_PREALLOCATE=false
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1 | tee "$OUT/device_light.log"
# shellcheck disable=SC2086  # DEVICE_LIGHT_ARGS holds several arguments
python3 benchmarks/device_light.py run --out "$OUT" $DEVICE_LIGHT_ARGS 2>&1 | tee -a "$OUT/device_light.log"
