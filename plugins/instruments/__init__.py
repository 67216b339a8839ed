"""Instrument drivers used by the ``lab`` backend (no plugin registration here).

* :mod:`mbus_plugins.instruments.ds340`: SRS DS340 function/arbitrary generator on RS-232 (pyserial);
* :mod:`mbus_plugins.instruments.gds2000`: GW Instek GDS-2000 oscilloscope (GDS-2062) on its USB
  serial port or RS-232 (pyvisa, ASRL resource);
* :mod:`mbus_plugins.instruments.shots`: the on-disk shot format the ``lab`` backend writes and the
  ``file`` backend reads back, and the shot processing (alignment, averaging) both share;
* :mod:`mbus_plugins.instruments.gds_csv`: CSV files saved by a GDS-2000 on its USB disk.

Every failure is an :class:`~mbus_framework.errors.InstrumentError` whose one-line message
starts with ``"<instrument>: <step>: "``.
"""
