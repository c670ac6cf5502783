#!/usr/bin/env bash
# Wheels for benchmarks/gpu_check.sh on a GPU machine that cannot reach PyPI: the packages this project
# needs beyond what such an image already holds (JAX, flax, optax, orbax, numpy, rich, ...), at the
# versions installed in the environment running this script (install the project there first), for
# CPython $PYVER (default 3.12) on x86-64 Linux, into .whl/ (git-ignored; carried with the checkout).
set -euo pipefail
cd "$(dirname "$0")/.."
pyver="${PYVER:-3.12}"
names="mujoco mujoco-core mujoco-mjx mujoco-studio brax jaxopt ml-collections trimesh tensorboardx glfw pyopengl
       flask flask-cors blinker itsdangerous websockets nest-asyncio tyro docstring-parser typeguard
       eval-type-backport gymnasium farama-notifications tzdata"
pins=$(python3 - $names <<'PY'
import importlib.metadata as md, sys
def pin(n):
    try:
        return f"{n}=={md.version(n)}"
    except md.PackageNotFoundError:  # a conditional requirement this environment did not need
        return ""
print(" ".join(filter(None, map(pin, sys.argv[1:]))))
PY
)
mkdir -p .whl
# shellcheck disable=SC2086
python3 -m pip download --quiet --no-deps --only-binary=:all: --dest .whl --python-version "$pyver" \
  --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any $pins
ls .whl
