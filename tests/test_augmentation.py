import numpy as np
import jax.numpy as jnp

from parallel_skills.replay import Transition
from parallel_skills.augmentation import (augment_batch, augment_labels, augment_labels_indexed,
                                          with_augmentation)


def test_k60_kmin10_full_execution():
    c = np.arange(60, 0, -1)  # 60..1
    k_aug, c_aug, dec, applies = augment_labels(jnp.full(60, 60), jnp.asarray(c), 10)
    np.testing.assert_array_equal(k_aug, np.full(60, 10))
    np.testing.assert_array_equal(c_aug, np.tile(np.arange(10, 0, -1), 6))
    assert applies.all()
    np.testing.assert_array_equal(np.nonzero(np.asarray(dec))[0], np.arange(0, 60, 10))
    np.testing.assert_array_equal(c[np.asarray(dec)], [60, 50, 40, 30, 20, 10])


def test_paper_formula_counterexample():
    # c = 51, k_min = 10: the paper's printed formula gives 11; intended is 1.
    _, c_aug, dec, _ = augment_labels(jnp.array([60]), jnp.array([51]), 10)
    assert int(c_aug[0]) == 1 and not bool(dec[0])


def test_cut_short_by_episode_end():
    c = np.arange(60, 37, -1)  # 23 steps: 60..38
    assert len(c) == 23
    k_aug, c_aug, dec, applies = augment_labels(jnp.full(23, 60), jnp.asarray(c), 10)
    expected = np.concatenate([np.arange(10, 0, -1), np.arange(10, 0, -1), [10, 9, 8]])
    np.testing.assert_array_equal(c_aug, expected)
    np.testing.assert_array_equal(np.nonzero(np.asarray(dec))[0], [0, 10, 20])
    assert applies.all()


def test_not_a_multiple_unchanged_and_kmin_itself():
    k = jnp.array([15, 15, 10, 10, 25])
    c = jnp.array([15, 7, 10, 3, 25])
    k_aug, c_aug, dec, applies = augment_labels(k, c, 10)
    np.testing.assert_array_equal(k_aug, k)
    np.testing.assert_array_equal(c_aug, c)
    np.testing.assert_array_equal(applies, [False] * 5)
    np.testing.assert_array_equal(dec, [True, False, True, False, True])


def test_indexed_and_batch():
    K = (10, 15, 20, 30)
    k_idx = jnp.array([2, 2, 1, 3, 0])
    c = jnp.array([20, 11, 15, 21, 10])
    k_idx_aug, c_aug, dec, applies = augment_labels_indexed(k_idx, c, K)
    np.testing.assert_array_equal(k_idx_aug, [0, 0, 1, 0, 0])
    np.testing.assert_array_equal(c_aug, [10, 1, 15, 1, 10])
    np.testing.assert_array_equal(dec, [True, False, True, False, True])
    np.testing.assert_array_equal(applies, [True, True, False, True, False])
    z = jnp.zeros(5)
    batch = Transition.batch(obs=z[:, None], reward=z, discount=z, next_obs=z[:, None], k_idx=k_idx, c=c,
                             is_decision=jnp.array([True, False, True, False, True]), skill=jnp.arange(5))
    aug = augment_batch(batch, K)
    np.testing.assert_array_equal(aug.weight, [1, 1, 0, 1, 0])
    np.testing.assert_array_equal(aug.skill, np.arange(5))
    both = with_augmentation(batch, K)
    assert both.c.shape == (10,)
    np.testing.assert_array_equal(both.c, [20, 11, 15, 21, 10, 10, 1, 15, 1, 10])
