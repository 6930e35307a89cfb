"""Command-line entry points: ``python -m runners.<name>``. Installed as ``sagp_batched_runners``."""
