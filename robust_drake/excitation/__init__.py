"""Experiment design for identification: optimised periodic excitations (:mod:`.design`)."""
