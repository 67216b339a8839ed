"""The built-in plugins of mbus, installed as ``mbus_plugins``; each module is found through an
entry point of the group ``mbus_framework``, as a third-party plugin is.

:data:`MBUS_PLUGIN_NAMES` says which names each module registers, so that the plugin manager
imports a module only when a config uses one of its names (a potato run imports five of the
eighteen); ``--list-plugins`` imports them all. ``tests/test_plugins_lazy.py`` checks the table
against what the modules' hooks return.
"""

#: Entry-point module -> {kind: names its hooks register}.
MBUS_PLUGIN_NAMES = {
    "mbus_plugins.models.kelvin_voigt": {"model": ("kelvin_voigt",)},
    "mbus_plugins.models.maxwell": {"model": ("maxwell",)},
    "mbus_plugins.models.sls": {"model": ("sls",)},
    "mbus_plugins.models.generalized_maxwell": {"model": ("generalized_maxwell",)},
    "mbus_plugins.models.layered": {"model": ("layered",)},
    "mbus_plugins.models.continuum_layer": {"model": ("continuum_layer", "fractional_zener")},
    "mbus_plugins.excitations.prbs": {"excitation": ("prbs",)},
    "mbus_plugins.excitations.sine_sweep": {"excitation": ("sine_sweep",)},
    "mbus_plugins.excitations.multisine": {"excitation": ("multisine",)},
    "mbus_plugins.excitations.from_file": {"excitation": ("from_file",)},
    "mbus_plugins.backends.simulated": {"backend": ("simulated",)},
    "mbus_plugins.backends.file": {"backend": ("file",)},
    "mbus_plugins.backends.lab": {"backend": ("lab",)},
    "mbus_plugins.solvers.scipy_lm": {"solver": ("scipy_lm",)},
    "mbus_plugins.solvers.frequency_domain": {"solver": ("frequency_domain",)},
    "mbus_plugins.solvers.casadi_collocation": {"solver": ("casadi_collocation",)},
    "mbus_plugins.compensators.none": {"compensator": ("none",)},
    "mbus_plugins.compensators.transfer_function": {"compensator": ("transfer_function",)},
}
