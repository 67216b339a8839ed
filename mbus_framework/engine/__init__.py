"""The engine: exact discrete-time simulation, chain assembly from link laws, physics helpers.

Depends only on the interfaces. Everything that simulates a medium model goes through
:mod:`mbus_framework.engine.simulation`.
"""
