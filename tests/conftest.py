"""Shared test setup: JAX's persistent compilation cache (compiles dominate test time) and
session-scoped fixtures so that compiled functions are shared across tests."""

from __future__ import annotations

import os

# Tests check behaviour, never speed, and compiling dominates most of their time: XLA compiles with
# most optimisations off (JAX's own switch; on this CPU about 30 % less CPU time for a training
# test). Set before JAX starts; the commands the tests start inherit it. A test whose run time
# dominates (MJX physics runs tens of times slower so) asks for ``full_optimisation``.
os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"

import jax  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

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


@pytest.fixture(scope="module")
def full_optimisation():
    """XLA's default optimisation from the first test of a module that asks for it to the module's
    end, for tests that step MJX physics many times (an agent step of 8 envs: ~3 s with most
    optimisations off, ~0.04 s with them on). JAX's in-memory caches are cleared on entry and exit
    so that neither level's executables serve the other (the persistent cache keys on the options)."""
    jax.clear_caches()
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", True)
        jax.clear_caches()


@pytest.hookimpl(optionalhook=True)  # (a hook of pytest-xdist: unknown under -p no:xdist)
def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject's addopts): one worker per core this process may run on, at most 4 (a
    worker compiling a training iteration holds up to ~5 GB)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(4, cores))

# The files whose tests take longest, longest first (seconds on one loaded core, measured: README
# commands ~570, the training entry points ~450, sharding ~370, the chain ~350, resume ~340, MJX
# physics ~330, seed groups ~320, baselines ~300, the accelerator smoke ~280). pytest-xdist hands
# files to workers in collection order (``--no-loadscope-reorder``: not by their number of tests),
# so the long files start first and the run does not end on one long file while the other worker idles.
LONGEST_FIRST = ("test_readme.py", "test_train.py", "test_sharding.py", "test_chain.py", "test_resume.py",
                 "test_physics_domain.py", "test_seeds_cli.py", "test_baselines.py", "test_accelerator_bench.py",
                 "test_kinematic.py", "test_skill_library.py", "test_export.py", "test_scheduler_nstep.py")


def pytest_collection_modifyitems(session, config, items):
    """Order the collected files by ``LONGEST_FIRST``, the others after them as collected."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
