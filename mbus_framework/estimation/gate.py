"""Is there anything to estimate? The gate for records the model cannot explain.

Every parameter can be given a small standard error at *some* point of a flat, noisy cost
(the linearisation knows nothing of the noise far from the data), so the numbers alone cannot
say that a record holds no information. Three model-free figures do:

* **explained variance** 1 - ||r||^2 / ||y - mean(y)||^2 of the fit (near 0: the model explains
  nothing; 0.1 is noise at 300 % of the signal RMS);
* **response test**: the residual-input F test (:mod:`mbus_framework.estimation.acceptance`)
  applied to the record itself: is any part of y a linear response to u at all?
* **signal-to-noise** power ratio of the prediction over the residual variance.

A record is unreliable when the explained variance is below ``min_explained_variance``
(default 0.25, noise above ~170 % of the signal RMS) or no response is detectable
(p > 0.001); then every parameter carries an unreliability warning.

The response test is model-free and can miss a response the fit plainly finds: a slow, highly
damped sample (a potato of low E_sigma and high eta_sigma) answers a white input later than
the test's N/16 lags, smeared over hundreds of samples, so neither the FIR nor a single
cross-correlation lag stands out (p = 0.24 at signal-to-noise 100 on such a record). A fit
that explains the record at signal-to-noise >= :data:`MIN_SIGNAL_TO_NOISE` with every free
parameter precise (relative SE <= ``precise``) has found the response: a fit to noise cannot
do that (its explained variance is ~p/N), so then the response test does not count.
"""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation.acceptance import residual_input_test

MIN_SIGNAL_TO_NOISE = 10.0
"""Power ratio var(yhat) / s^2 above which a fit with precise parameters shows the response
itself (prediction RMS > 3 x residual RMS; explained variance > 0.9)."""


def information_gate(y: np.ndarray, residuals: np.ndarray, u: np.ndarray, min_explained_variance: float = 0.25,
                     significance: float = 1e-3, relative_standard_errors=None, precise: float = 0.05) -> dict:
    """The figures of the module docstring and the verdict ``reliable``; ``relative_standard_errors``
    (of the free parameters, None: unknown) let a precise, high signal-to-noise fit stand for
    the response test."""
    y = np.asarray(y, dtype=float)
    r = np.asarray(residuals, dtype=float)
    centred = y - y.mean()
    total = float(centred @ centred)
    rr = float(r @ r)
    explained = 1.0 - rr / total if total > 0 else 0.0
    response = residual_input_test(centred, u, 0)
    yhat = y - r
    snr = float(np.var(yhat) / (rr / r.size)) if rr > 0 else float("inf")
    reasons = []
    if explained < min_explained_variance:
        reasons.append(f"the model explains {100 * max(explained, 0.0):.2g} % of the record's variance")
    rse = np.asarray([] if relative_standard_errors is None else list(relative_standard_errors), dtype=float)
    fit_shows_response = bool(snr >= MIN_SIGNAL_TO_NOISE and rse.size and np.all(np.isfinite(rse))
                              and np.all(rse <= precise))
    if response.p_value > significance and not fit_shows_response:
        reasons.append(f"no response to the input is detectable in the record (p = {response.p_value:.2g})")
    return {
        "explained_variance": float(explained),
        "signal_to_noise": snr,
        "response_p_value": float(response.p_value),
        "response_shown_by_fit": fit_shows_response,
        "reliable": not reasons,
        "reason": "; ".join(reasons),
    }
