"""Calibration of MBUS estimates against conventional mechanical tests (Chapter 6, Table 6.1).

``model`` joins the campaign table to the conventional measurements and regresses one on the
other (``regression``: straight-line fits with intervals), ``property_calibration`` is a saved
calibration applied to new tables, ``plots`` the figures and ``command`` the ``mbus-analyze
calibrate`` / ``apply-calibration`` arguments. Users import::

    from mbus_framework.analysis.calibrate import calibrate, PropertyCalibration
"""
from mbus_framework.analysis.calibrate.model import CalibrationAnalysis, calibrate
from mbus_framework.analysis.calibrate.property_calibration import PropertyCalibration

__all__ = ["CalibrationAnalysis", "PropertyCalibration", "calibrate"]
