"""PACHS in JAX: batched actor-critic heuristic search over MuJoCo MJX tasks."""

__version__ = '0.1.0'
