"""Estimation: the fitting problem and solver interface, nuisance parameters (gain, delay),
the global search strategy and parameter uncertainty."""
