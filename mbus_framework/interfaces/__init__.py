"""Plugin interfaces and their registry: what a plugin implements and how it is found.

Medium models, excitations, instrument backends and compensators (behaviour interfaces as
ABCs), the sample geometry they share, the pluggy hook specifications that *register*
implementations, the plugin manager that loads them through entry points, and the registry
that looks them up by kind and name. The solver interface lives with the fitting problem in
:mod:`mbus_framework.estimation.problem`.
"""
