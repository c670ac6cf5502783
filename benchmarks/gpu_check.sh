#!/usr/bin/env bash
# The device check in one call: the paper preset's environment throughput and training throughput,
# compile times and a short learning run's success, then more environment sizes, written to one JSON
# (benchmarks/gpu_check.py says what each stage measures) that is rewritten after every measurement and
# records the interpreter and every package version it ran with. It stops itself inside
# $GPU_CHECK_TIMEOUT seconds (default 480), keeping what it measured.
#
#   benchmarks/gpu_check.sh [OUT.json] [extra options of benchmarks.gpu_check, e.g. --tiny]
#
# On a machine that lacks the project's simulator packages (a bare GPU image has JAX but not MuJoCo,
# brax or tyro), the wheels in .whl/ are installed the way such a device expects, into a folder of
# their own ($GPU_CHECK_SITE, default /tmp/site) put on PYTHONPATH, leaving the image's interpreter
# untouched: make them beside the checkout with benchmarks/gpu_wheels.sh and let them travel with it.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-outputs/gpu_check.json}"
shift || true
py="${PYTHON:-python3}"
probe="import mujoco.mjx, brax, tyro, gymnasium, orbax.checkpoint, flax, optax"
if ! "$py" -c "$probe" >/dev/null 2>&1; then
  if ! compgen -G ".whl/*.whl" >/dev/null; then
    echo "gpu_check: the project's packages are missing and there is no .whl/ folder (benchmarks/gpu_wheels.sh)" >&2
    exit 2
  fi
  site="${GPU_CHECK_SITE:-/tmp/site}"
  "$py" -m pip install --quiet --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$site" .whl/*.whl
  export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}"
  if ! "$py" -c "$probe"; then
    echo "gpu_check: still missing after installing .whl/ into $site (the import error is above)" >&2
    exit 2
  fi
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # the checkout itself, installed or not
export PYTHONUNBUFFERED=1
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
# SIGINT first: the check saves its JSON and exits; SIGKILL 20 s later if it did not.
exec timeout --signal=INT --kill-after=20 "${GPU_CHECK_TIMEOUT:-480}" "$py" -m benchmarks.gpu_check --out "$out" "$@"
