"""Experiments on the simulator: data collection and steering setups (:mod:`.pipeline`),
``make demo`` (:mod:`.demo`) and ``make bench`` (:mod:`.bench`)."""
