"""mbus: model-based ultrasound (MBUS) evaluation of viscoelastic materials.

The core defines the interfaces (medium models, excitations, solvers, compensators,
instrument backends), the plugin system, configuration, the exact simulator, the global
estimation strategy and the run pipeline; implementations live in plugins.
"""
__version__ = "0.1.0"
