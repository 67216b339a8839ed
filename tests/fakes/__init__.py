"""Byte-exact fake instruments for hardware-free tests.

* :class:`~fakes.pty_device.PtyDevice`: a thread that plays an instrument on the master side of
  a pseudo-terminal (``os.openpty``); the driver opens ``device.port`` as a real serial port.
* :class:`~fakes.ds340.FakeDS340`, :class:`~fakes.gds2000.FakeGDS2000`: the two instruments, with
  fault switches (silence, garbage, rejected commands, short blocks, disconnects).
* :class:`~fakes.bench.Bench`: wires the generator's output through a simulated medium to the
  scope's channels.
* ``gds2062.yaml``: a pyvisa-sim description of the scope's text commands.
"""
