"""BOP results files: the CSV reader and writer (bop_csv.py), file names and the run sidecar (files.py),
PVNet-style conversion (convert_pvnet.py)."""
