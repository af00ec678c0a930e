"""Numerical optimisers that know nothing of the method: the lockstep Nelder-Mead of stages 2 and 3.

Below ``centers`` (stage 2) and ``pose`` (stage 3), which both import it; it imports nothing of ``bop_cender``.
"""
