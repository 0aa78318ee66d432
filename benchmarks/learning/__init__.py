"""Learning benchmarks: ``python -m benchmarks.learning.NAME --help``."""
