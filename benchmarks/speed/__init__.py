"""Speed benchmarks: ``python -m benchmarks.speed.NAME --help``."""
