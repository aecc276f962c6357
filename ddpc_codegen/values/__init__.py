"""Values that the design side and the runtime side share: the steering config, a solve's result, the fit's
layout, the online update's settings, the hop phases, the prefilter model, an artificial-IO completion.

numpy only; imports nothing of the project but itself and :mod:`ddpc_codegen.errors` (enforced by
``tests/test_layout.py``), so that either side can hold these values without loading the other.
"""
