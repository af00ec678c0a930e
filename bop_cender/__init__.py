"""bop-cender: CenDerNet multi-view 6D pose estimation as a BOP method, with its own BOP harness."""

__version__ = "0.1.0"
