"""Reusable contract test suites for mbus plugins (for plugin authors and our own tests)."""
