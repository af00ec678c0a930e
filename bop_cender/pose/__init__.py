"""Stage 3: render-and-compare pose estimation, module by job.

- ``sweeps``: the entry, :func:`~bop_cender.pose.sweeps.optimise_scene` (the first placement, further sweeps, the
  scene polish's passes), on a ``context`` (:func:`~bop_cender.pose.context.scene_context`, one per scene);
- ``search``: one object's candidates, their ranking, the screen and the refinement; ``nelder_mead``: its bounded
  lockstep Nelder-Mead (on :mod:`bop_cender.optim.simplex`); ``problem``: what one object is costed against;
  ``center_term``, ``occluders``;
- ``judge`` and ``polish``: the whole placement's cost and the scene polish;
- ``config`` (the settings' sections; old names in ``config_names``) and ``types`` (what flows between the steps);
- the costs themselves: ``cost`` (render), ``edge_cost`` (edge-point proxy), ``coverage`` (scene cost),
  ``scene_polish`` (windowed scene cost), and their compiled kernels.
"""
