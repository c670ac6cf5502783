"""Comparing agents: `study` (one comparison's settings as one value, `Study`), `reproduce` (train the
four agents per seed, score them per shape, report), `jobs` (the process pool), `cache` (each run's
cached evaluations), `protocol` (a pre-registered comparison's runs, each recorded as it ends), `tables`
(its tables and claims printed from the committed records), `seed_stats` (intervals over training
seeds), `report` (reproduce's Markdown report and figures)."""
