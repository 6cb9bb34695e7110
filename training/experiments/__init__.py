"""Longer experiments and diagnostics (not part of the test suite)."""
