"""Classification of materials from their estimated properties (Chapter 4, Tables 4.4/4.5).

``model`` holds k-means and linear discriminant analysis with leave-one-out validation,
``report`` the tables and JSON, ``plots`` the figures, ``command`` the ``mbus-analyze
classify`` arguments. Users import::

    from mbus_framework.analysis.classify import classify, feature_sets
"""
from mbus_framework.analysis.classify.model import Classification, MethodResult, classify, feature_sets

__all__ = ["Classification", "MethodResult", "classify", "feature_sets"]
