"""The error-against-run-time report of a trained avatar (`python -m benchmarks.error_vs_time`):
per-LOD sweep, smoothness, stability, ablations."""
