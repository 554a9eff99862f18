"""A run's numbers: metrics, membership, safety, the run record, DataFrames, the report."""
