#!/usr/bin/env bash
# The device check in one call: environment throughput at 1,024-8,192 envs, the paper preset's training
# throughput and compile times, and a short learning run's success, written to one JSON
# (benchmarks/gpu_check.py says what each stage measures). Sized to finish in about 7 minutes on one
# GPU; the JSON is rewritten after every stage, so a timeout keeps what was measured.
#
#   benchmarks/gpu_check.sh [OUT.json] [extra options of benchmarks.gpu_check, e.g. --tiny]
#
# On a machine that lacks the project's simulator packages (a bare GPU image has JAX but not MuJoCo,
# brax or tyro), wheels in .whl/ are installed first: make them beside the checkout with
# benchmarks/gpu_wheels.sh (where pip can reach PyPI) and let them travel with it.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-outputs/gpu_check.json}"
shift || true
py="${PYTHON:-python3}"
if ! "$py" -c "import mujoco.mjx, brax, tyro, gymnasium, orbax.checkpoint" >/dev/null 2>&1; then
  if [ -d .whl ]; then
    "$py" -m pip install --quiet --no-index --find-links .whl --no-deps .whl/*.whl
  else
    echo "gpu_check: the project's packages are missing and there is no .whl/ folder (benchmarks/gpu_wheels.sh)" >&2
    exit 2
  fi
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # the checkout itself, installed or not
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
exec "$py" -m benchmarks.gpu_check --out "$out" "$@"
