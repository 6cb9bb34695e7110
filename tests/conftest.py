"""Shared test setup: JAX's persistent compilation cache (compiles dominate test time) and
session-scoped fixtures so that compiled functions are shared across tests."""

from __future__ import annotations

import os

import jax
import pytest
from hypothesis import settings

# Property tests draw the same examples on every run (CI reruns a clean clone at each stop: a new
# draw must not turn it red by chance); ``HYPOTHESIS_PROFILE=explore`` draws new ones, to search.
settings.register_profile("repro", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repro"))

_CACHE = os.environ.get("PARALLEL_SKILLS_TEST_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "parallel_skills_jax"))
jax.config.update("jax_compilation_cache_dir", _CACHE)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


@pytest.fixture
def one_core():
    """Pin the test process to one core while the test runs: MJX-jax can deadlock on this 2-core
    CPU otherwise (shared/STACK.md)."""
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    saved = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(saved)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, saved)
