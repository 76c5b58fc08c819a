"""gvnn_warp benchmarks: ``python -m benchmarks.run`` (see run.py)."""
