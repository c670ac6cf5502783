"""CPU XLA flag, applied before JAX initialises its backend.

With jaxlib 0.10.x the CPU fusion emitters make MJX kinematics exponentially slow in the depth of
the kinematic tree (jax-ml/jax#33761, google-deepmind/mujoco#2957): a 7-joint arm runs ~500x slower.
Importing this module (every package entry point does, first) adds the flag unless the user already
set it either way in their own XLA_FLAGS.
"""

import os

FLAG = "--xla_cpu_use_fusion_emitters"


def apply_cpu_flags() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if FLAG not in flags:
        os.environ["XLA_FLAGS"] = (flags + f" {FLAG}=false").strip()


apply_cpu_flags()
