#!/usr/bin/env bash
# Wheels for benchmarks/gpu_check.sh on a GPU machine that cannot reach PyPI: the packages this project
# needs beyond what such an image already holds (JAX, flax, optax, orbax, numpy, rich, ...), at the
# versions installed in the interpreter $PYTHON (default python3; install the project there first), for
# CPython $PYVER (default 3.12) on x86-64 Linux, into .whl/ (git-ignored; carried with the checkout).
# Fails, naming them, when a needed package is not installed in $PYTHON or a wheel does not download:
# an empty pin list would otherwise download nothing and the device session would find out too late.
set -euo pipefail
cd "$(dirname "$0")/.."
py="${PYTHON:-python3}"
pyver="${PYVER:-3.12}"
# Needed on every Python; the second list only where a marker asks for them (older Pythons).
needed="mujoco mujoco-core mujoco-mjx mujoco-studio brax jaxopt ml-collections trimesh tensorboardx glfw
        pyopengl flask flask-cors blinker itsdangerous websockets tyro docstring-parser typeguard gymnasium
        farama-notifications tzdata"
conditional="nest-asyncio eval-type-backport"
# shellcheck disable=SC2086
pins=$("$py" - "$needed" "$conditional" <<'PY'
import importlib.metadata as md, sys
needed, conditional = sys.argv[1].split(), sys.argv[2].split()
def version(n):
    try:
        return md.version(n)
    except md.PackageNotFoundError:
        return None
missing = [n for n in needed if version(n) is None]
if missing:
    sys.exit(f"gpu_wheels: not installed in {sys.executable}: {' '.join(missing)} "
             "(install the project there first: pip install -e .)")
print(" ".join(f"{n}=={version(n)}" for n in needed + conditional if version(n) is not None))
PY
)
mkdir -p .whl
# shellcheck disable=SC2086
"$py" -m pip download --quiet --no-deps --only-binary=:all: --dest .whl --python-version "$pyver" \
  --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any $pins
# Every pin must have its wheel (pip download stops on a missing one; this also catches stale names).
"$py" - .whl $pins <<'PY'
import re, sys
from pathlib import Path
names = {re.sub(r"[-_.]+", "_", p.name.split("-")[0]).lower() for p in Path(sys.argv[1]).glob("*.whl")}
absent = [p for p in sys.argv[2:] if re.sub(r"[-_.]+", "_", p.split("==")[0]).lower() not in names]
if absent:
    sys.exit(f"gpu_wheels: no wheel in .whl/ for {' '.join(absent)}")
print(f"gpu_wheels: {len(sys.argv) - 2} wheels in .whl/")
PY
du -sh .whl
