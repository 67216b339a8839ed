"""Joint estimation over several records of one material (replicates, thicknesses, excitations).

Each record r keeps its own geometry, excitation, sample rate and noise level sigma_r; the
material properties named ``shared`` are one vector for all records, everything else (the
remaining properties, the nuisance ``input_gain`` and ``delay``) is per record. The joint
maximum-likelihood estimate minimises

    cost(phi) = 1/2 sum_r ||(y_r - yhat_r(phi)) / sigma_r||^2

with sigma_r from record r's own fit. :mod:`~mbus_framework.joint.spec` declares what is shared,
:mod:`~mbus_framework.joint.problem` stacks the records (exact block Jacobian),
:mod:`~mbus_framework.joint.estimate` fits and tests agreement, :mod:`~mbus_framework.joint.result`
reports, :mod:`~mbus_framework.joint.run` reads a joint config and runs it.
"""
__all__ = ["JointSpec"]


def __getattr__(name: str):  # PEP 562: recognising a joint config must not import the estimator
    if name == "JointSpec":
        from mbus_framework.joint.spec import JointSpec

        return JointSpec
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
