"""Reports of scored runs: comparison tables and charts (tables.py), score summaries (summary.py)."""
