"""Prediction of sensory crispness from MBUS estimates (Chapter 7).

``network`` and ``regressor`` are the one-hidden-layer perceptron trained by
Levenberg-Marquardt (a scikit-learn regressor), ``validation`` the leave-one-out prediction,
structure comparison and sensitivities (eq. 7.2), ``panel`` the sensory panel's scores
(Tables 7.1-7.3), ``agreement`` Fisher's z tests, ``model`` the saved model ``predict`` uses,
``workflow`` / ``report`` / ``plots`` / ``command`` the ``mbus-analyze crispness`` and
``predict`` subcommands, ``virtual_panel`` the panel of the shipped virtual campaign. Users
import::

    from mbus_framework.analysis.crispness import LMNetworkRegressor, leave_one_out
"""
from mbus_framework.analysis.crispness.model import CrispnessModel
from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor
from mbus_framework.analysis.crispness.validation import leave_one_out, sensitivities, structure_comparison

__all__ = ["CrispnessModel", "LMNetworkRegressor", "leave_one_out", "sensitivities", "structure_comparison"]
