"""The solver build path: config + dataset -> checked data -> predictor -> generated, compiled solver.

:func:`~ddpc_codegen.pipeline.solver_build.build_solver` is what the command line, the simulated
experiments, the sweep and the benches call; it sits downstream of ``design/`` and ``codegen/``.
"""
