"""Conventional mechanical tests of Chapter 6, reduced to the four MBUS properties.

* :mod:`.compression`: cyclic compression records (time, force, displacement at a known
  frequency) -> stiffness k and damping b of ``b dx/dt + k x = u`` (eq. 6.14) -> E, eta
  (eqs. 6.14-6.23), with standard errors from the sinusoid fit.
* :mod:`.rheometer`: shear frequency sweeps (frequency, E', E'', eta') -> E' and eta' at a
  chosen frequency (about 10 Hz in the dissertation).
* :mod:`.sheet`: the conventional sheet that lists the record files per sample id, and the
  per-sample table (replicates averaged) that the calibration joins to the campaign table.
* :mod:`.synthetic`: records and sweeps from known properties (tests, virtual campaigns).
"""
