"""Tests of `roadlink.services`, a module per module. `problems.py` is pure declarations (the
problem item model and the exception that carries one), with no module of its own: every
service test that expects a refusal checks the `ServiceProblem` it raises."""
