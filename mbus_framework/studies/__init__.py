"""Applications over the run pipeline: the Chapter 3 studies (Monte Carlo, element sweep,
repeatability), model comparison, excitation design and transducer calibration (Chapter 5)."""
