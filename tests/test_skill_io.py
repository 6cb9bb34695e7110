"""Skill save / load round trip, size validation, and the JAX-free NumPy forward pass."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from parallel_skills import Skill
from parallel_skills import networks
from parallel_skills.numpy_policy import NumpyGaussianPolicy


def _skill(obs_size=60, action_size=5, hidden=(32, 64, 32)):
    net = networks.GaussianPolicy(action_size=action_size, hidden=hidden)
    params = net.init(jax.random.PRNGKey(0), jnp.zeros((1, obs_size)))
    # Perturb so that the head is not ~0 (its init is tiny) and the test sees real outputs.
    params = jax.tree.map(lambda x: x + 0.3 * jax.random.normal(jax.random.PRNGKey(1), x.shape), params)
    stats = {"obs_mean": jnp.linspace(-0.1, 0.1, obs_size), "obs_std": jnp.linspace(0.05, 0.5, obs_size)}
    return Skill.gaussian_mlp("test_skill", {"policy": params, **stats}, action_size, hidden, obs_size=obs_size)


def test_save_load_roundtrip_and_numpy_forward(tmp_path):
    skill = _skill()
    path = str(tmp_path / "s.npz")
    skill.save(path, task="lift", success=0.5)
    meta = json.load(open(tmp_path / "s.json"))
    assert meta["obs_size"] == 60 and meta["action_size"] == 5 and meta["hidden"] == [32, 64, 32]
    loaded = Skill.load(path, obs_size=60, action_size=5)
    obs = jax.random.normal(jax.random.PRNGKey(2), (16, 60)) * 0.2
    a_jax = jax.vmap(lambda o: skill.apply(skill.params, o, None))(obs)
    a_loaded = jax.vmap(lambda o: loaded.apply(loaded.params, o, None))(obs)
    np.testing.assert_allclose(np.asarray(a_loaded), np.asarray(a_jax), atol=1e-6)
    a_np = NumpyGaussianPolicy.load(path)(np.asarray(obs, np.float64))
    assert np.max(np.abs(a_np - np.asarray(a_jax))) <= 1e-5
    assert np.std(a_np) > 1e-3  # outputs are not trivially constant


def test_load_rejects_mismatch_and_corrupt_files(tmp_path):
    path = str(tmp_path / "s.npz")
    _skill().save(path)
    with pytest.raises(ValueError, match="expects observations of size 60, the task gives 59"):
        Skill.load(path, obs_size=59)
    with pytest.raises(ValueError, match="produces actions of size 5, the task takes 4"):
        Skill.load(path, action_size=4)
    with open(path, "r+b") as f:  # truncate the archive
        f.truncate(100)
    with pytest.raises(ValueError, match="cannot read skill"):
        Skill.load(path)
    with pytest.raises(ValueError, match="does not exist"):
        Skill.load(str(tmp_path / "missing.npz"))
    assert os.path.exists(path)  # a failed load never deletes anything

