"""Watching and drawing a run: the live view, rerun and MCAP recordings, the map painter, the
benchmarks' plots (docs/viewing.md)."""
