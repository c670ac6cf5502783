"""train: vision autoencoder and the pure-JAX SAC + HER learner."""

from mjx_push import xla as _xla  # noqa: F401  (must run before jax initialises)
