"""Experiment runs: recording, the frames of a run, and exports (CSV, Parquet, MCAP)."""
