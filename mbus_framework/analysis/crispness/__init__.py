"""Prediction of sensory crispness from MBUS estimates (Chapter 7).

``network`` and ``regressor`` are the one-hidden-layer perceptron trained by
Levenberg-Marquardt (a scikit-learn regressor), ``validation`` the leave-one-out prediction,
structure comparison and sensitivities (eq. 7.2), ``panel`` the sensory panel's scores
(Tables 7.1-7.3), ``agreement`` Fisher's z tests, ``model`` the saved model ``predict`` uses,
``workflow`` / ``report`` / ``plots`` / ``command`` the ``mbus-analyze crispness`` and
``predict`` subcommands, ``virtual_panel`` the panel of the shipped virtual campaign. Users
import::

    from mbus_framework.analysis.crispness import LMNetworkRegressor, leave_one_out

Those names are imported on first use (PEP 562), so ``mbus-analyze`` reading the subcommands'
arguments does not load scikit-learn.
"""
import importlib

_WHERE = {"CrispnessModel": "model", "LMNetworkRegressor": "regressor", "leave_one_out": "validation",
          "cross_validate": "validation", "sensitivities": "validation", "structure_comparison": "validation"}

__all__ = list(_WHERE)


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
