"""Stable plugin-author name: ``mbus_framework.chain`` is ``mbus_framework.engine.chain``.

Plugins import the interfaces by their short names; the implementation lives in its
subpackage (see docs/architecture.md). This module *is* that module (one object, so
isinstance checks and private helpers behave the same under both names).
"""
import sys

from mbus_framework.engine.chain import __name__ as _target

sys.modules[__name__] = sys.modules[_target]
