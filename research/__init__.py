"""One-off diagnostics behind docs/research (not installed with the package; run from a checkout:
``python -m research.<name>``). Each module's docstring says what it measures and where its result
is recorded."""
