"""A training run's life on disk, apart from the algorithm: the run in its directory (`run`: train,
resume, fork, summary), its lock, orbax checkpoints, the fork's record, saved policies, the metric log,
stopping on a signal, atomic writes."""
