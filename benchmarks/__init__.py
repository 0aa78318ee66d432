"""Benchmarks, run from the checkout's root as modules: ``python -m benchmarks.speed.NAME`` (what the loop, the
update, the planner, the renderer and the collectors cost) and ``python -m benchmarks.learning.NAME`` (learning over
seeds, checkpoint scores, the scripted experts). They write JSON and plots; the diagnostics that look inside a
trained agent are ``python -m torchrl_mpail2.diagnostics``."""
