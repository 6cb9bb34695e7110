"""Experiment tools: ``paper`` (the paper's experiment matrix), ``results`` (the tables of
docs/results rebuilt from the archived runs), ``schedules`` (fixed skill schedules),
``time_to_success``. The one-off diagnostics of docs/research are in the top-level ``research/``
folder, which is not installed."""
