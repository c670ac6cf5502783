"""mjx_push: the batched Franka Panda pushing scene in MuJoCo MJX (simulation only, no learning)."""

from mjx_push import xla as _xla  # noqa: F401  (must run before jax initialises)

__version__ = "0.1.0"
