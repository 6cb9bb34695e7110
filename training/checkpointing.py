"""Full-state checkpoints of a training run (orbax-checkpoint), for exact resumption.

    ckpt = Checkpointer(run_dir, save_replay=True)
    train(..., checkpoint_fn=ckpt.save, checkpoint_every=M)           # writes RUN/checkpoints/<it>/
    state, host = ckpt.restore(abstract_training_state(env, skills, config, seed))
    train(..., initial_state=state, host_state=host)                   # continues the run exactly

One checkpoint is the directory ``RUN/checkpoints/<iteration>/``, written by orbax's
``CheckpointManager`` synchronously and atomically: orbax writes into a temporary directory and
renames it when complete, so a run killed mid-save leaves the earlier checkpoints intact (and the
unfinished temporary directory is ignored). The latest ``MAX_TO_KEEP`` (2) are kept. Items:

* ``state``: the whole ``parallel_skills.train.TrainingState`` but the replay buffer: scheduler
  and new-skill learner states (policy / critic params, their target networks, Adam states, MPO
  duals and their optimiser states, update counters), the actor state (per-env skill index,
  counter, length index, episode-start flags, running episode return / success and the batched
  env states), the observation normaliser, the run's RNG key, ``env_steps`` and ``iteration``.
* ``replay``: the replay buffer (flashbax state: every stored transition, the write index and
  the full flag). Not written with ``save_replay=False`` (``--no-replay-checkpoint``); a resume
  from such a checkpoint starts with an empty buffer (all else restored): the learners pause
  until it again holds their ``min_replay_size`` transitions, and the continuation is no longer
  identical to an uninterrupted run.
* ``host``: JSON of the host-side loop state: iteration, env_steps, the last evaluation's metrics,
  the training statistics accumulated since that evaluation, elapsed wall time, whether the
  replay was saved, and what ``training.run`` adds (the byte length and row count of
  ``metrics.csv`` that the checkpoint covers). The evaluation RNG key needs no saving: ``train``
  derives it from (seed, iteration).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Callable, Optional

CHECKPOINT_SUBDIR = "checkpoints"
MAX_TO_KEEP = 2


class CheckpointError(ValueError):
    """A checkpoint that cannot be restored into this run (missing, or not matching its state)."""


class CheckpointUnreadable(CheckpointError):
    """A checkpoint whose files do not restore (truncated or corrupt): its structure is not the
    cause, so an earlier checkpoint of the same run may restore (``Checkpointer.restore_latest``)."""


def _first_line(e: Exception) -> str:
    text = str(e).strip()
    return f"{type(e).__name__}: {text.splitlines()[0][:200] if text else ''}".rstrip(": ")


def abstract_training_state(environment, skills, config, seed: int):
    """``(abstract TrainingState, fresh_replay())`` of the run ``train(environment, skills,
    config=config, seed=seed)`` would start: shapes / dtypes / structure to restore into (nothing
    is computed), and a function returning the empty replay buffer of that run."""
    import jax

    from parallel_skills.config import resolve
    from parallel_skills.train import make_trainer

    trainer = make_trainer(environment, skills, resolve(config)[0])
    key = jax.random.PRNGKey(seed)
    abstract = jax.eval_shape(trainer.init, key)
    return abstract, lambda: jax.jit(lambda k: trainer.init(k).replay)(key)


def _like_fresh(tree, abstract, shardings=None):
    """Restored arrays as a fresh run holds them: uncommitted, with the abstract state's weak
    types (flashbax's write index is a weak int32). Either difference would make jit compile a
    different program for the same iteration (and miss the compilation cache). ``shardings``: the
    arrays were restored onto a mesh (possibly across processes); they stay there, weak types fixed."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    if shardings is not None:
        from jax._src.lax.lax import _convert_element_type  # no public API makes weak types

        def on_mesh(x, spec, sh):
            if not getattr(spec, "weak_type", False):
                return x
            return jax.jit(lambda a: _convert_element_type(a, spec.dtype, weak_type=True), out_shardings=sh)(x)

        return jax.tree.map(on_mesh, tree, abstract, shardings)

    def one(x, spec):
        a = np.asarray(x)
        if getattr(spec, "weak_type", False):
            if a.ndim == 0:
                out = jnp.asarray(a.item())  # a Python scalar gives a weak-typed array
                if out.dtype == spec.dtype and out.weak_type:
                    return out
            from jax._src.lax.lax import _convert_element_type  # no public API makes weak types

            return _convert_element_type(jax.device_put(a), spec.dtype, weak_type=True)
        return jax.device_put(a)

    return jax.tree.map(one, tree, abstract)


def _leaf_specs(tree) -> dict:
    """``{path: (shape, dtype)}`` of a tree's array leaves (abstract arrays or orbax's metadata),
    paths as strings of dict keys / attribute names / indices alike (orbax stores dataclasses as dicts)."""
    import jax
    import numpy as np

    def part(k):
        for attr in ("key", "name", "idx"):
            if hasattr(k, attr):
                return str(getattr(k, attr))
        return str(k)

    return {"/".join(part(k) for k in path): (tuple(leaf.shape), np.dtype(leaf.dtype).name)
            for path, leaf in jax.tree_util.tree_leaves_with_path(tree) if hasattr(leaf, "shape")}


def _mismatch(item_dir: str, abstract) -> Optional[str]:
    """Why the checkpoint item in ``item_dir`` cannot restore into ``abstract``, or None. Read from
    orbax's metadata before restoring: a failed restore leaves orbax's read coroutines behind, which
    print tracebacks to stderr when they are collected."""
    import orbax.checkpoint as ocp
    from etils import epath

    stored = _leaf_specs(ocp.StandardCheckpointHandler().metadata(epath.Path(item_dir)))
    wanted = _leaf_specs(abstract)
    for path in sorted(set(stored) | set(wanted)):
        if stored.get(path) != wanted.get(path):
            have = "absent" if path not in stored else "%s %s" % (stored[path][1], list(stored[path][0]))
            need = "absent" if path not in wanted else "%s %s" % (wanted[path][1], list(wanted[path][0]))
            return f"{os.path.basename(item_dir)}/{path} is {have} in the checkpoint, {need} in this run"
    return None


def _state_tree(state) -> dict:
    """The ``state`` item as written to disk: the TrainingState's fields as a dict, the replay as
    None (it is its own item), and optional fields that are None left out. Omitting them keeps
    every run's on-disk tree what it was before the field existed (``pending`` is None for 1-step
    runs: checkpoints written before it restore, and new 1-step ones match them); orbax stores a
    dataclass and a dict of its fields alike."""
    tree = {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}
    tree["replay"] = None
    return {k: v for k, v in tree.items() if v is not None or k == "replay"}


class Checkpointer:
    """Saves and restores checkpoints in ``run_dir/checkpoints`` (see the module docstring)."""

    def __init__(self, run_dir: str, *, save_replay: bool = True, max_to_keep: int = MAX_TO_KEEP):
        self.directory = os.path.abspath(os.path.join(run_dir, CHECKPOINT_SUBDIR))
        self.save_replay = bool(save_replay)
        self.max_to_keep = int(max_to_keep)
        self._manager = None

    def manager(self):
        """The orbax ``CheckpointManager`` of the directory (created on first use)."""
        if self._manager is None:
            import orbax.checkpoint as ocp

            options = ocp.CheckpointManagerOptions(max_to_keep=self.max_to_keep, create=True,
                                                   enable_async_checkpointing=False)
            self._manager = ocp.CheckpointManager(self.directory, options=options)
        return self._manager

    def steps(self) -> list[int]:
        """Iterations of the complete checkpoints on disk, ascending (unfinished saves excluded)."""
        if not os.path.isdir(self.directory):
            return []
        return sorted(int(s) for s in self.manager().all_steps())

    def latest_step(self) -> Optional[int]:
        steps = self.steps()
        return steps[-1] if steps else None

    def save(self, state, host_state: dict) -> None:
        """Write the checkpoint of iteration ``host_state["iteration"]`` (blocks until on disk)."""
        import orbax.checkpoint as ocp

        host = dict(host_state, replay_saved=self.save_replay)
        items = {"state": ocp.args.StandardSave(_state_tree(state)), "host": ocp.args.JsonSave(host)}
        if self.save_replay:
            items["replay"] = ocp.args.StandardSave(state.replay)
        mgr = self.manager()
        mgr.save(int(host["iteration"]), args=ocp.args.Composite(**items))
        mgr.wait_until_finished()

    def restore(self, abstract_state, fresh_replay: Optional[Callable] = None, step: Optional[int] = None,
                shardings=None):
        """``(TrainingState, host_state)`` of checkpoint ``step`` (default: the latest).

        ``abstract_state``: the run's state structure (``abstract_training_state``).
        ``fresh_replay()``: the empty buffer to start from when the checkpoint holds no replay.
        ``shardings``: a TrainingState of shardings (``parallel_skills.sharding.state_shardings``):
        each process reads its shards straight onto the run's mesh (multi-device / multi-process)."""
        import jax
        import orbax.checkpoint as ocp

        def target(tree, sh):
            """The restore target: ``tree``'s shapes placed as ``sh`` says, or on this process's first
            device (a checkpoint written on another mesh restores only onto an explicit placement)."""
            if sh is None:
                one = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
                return jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=one), tree)
            return jax.tree.map(lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s), tree, sh)

        step = self.latest_step() if step is None else int(step)
        if step is None:
            raise CheckpointError(f"no checkpoint in {self.directory}")
        mgr = self.manager()
        where = os.path.join(self.directory, str(step))
        try:
            host = mgr.restore(step, args=ocp.args.Composite(host=ocp.args.JsonRestore())).host
        except Exception as e:  # noqa: BLE001 - orbax raises several types for unreadable files
            raise CheckpointUnreadable(f"checkpoint {where} does not restore (host: {_first_line(e)})") from None
        if not isinstance(host, dict):
            raise CheckpointUnreadable(f"checkpoint {where} does not restore (host: not a JSON object)")
        state_sh = _state_tree(shardings) if shardings is not None else None
        items = {"state": ocp.args.StandardRestore(target(_state_tree(abstract_state), state_sh))}
        if host.get("replay_saved", True):
            items["replay"] = ocp.args.StandardRestore(
                target(abstract_state.replay, None if shardings is None else shardings.replay))
        for name, item in items.items():
            try:
                why = _mismatch(os.path.join(where, name), item.item)
            except Exception as e:  # noqa: BLE001 - its metadata does not read
                raise CheckpointUnreadable(f"checkpoint {where} does not restore ({name}: {_first_line(e)})") from None
            if why:
                raise CheckpointError(f"checkpoint {where} does not match this run's training state ({why})")
        try:
            restored = mgr.restore(step, args=ocp.args.Composite(**items))
        except Exception as e:  # noqa: BLE001 - the structure matched: the files are truncated or corrupt
            raise CheckpointUnreadable(f"checkpoint {where} does not restore ({_first_line(e)})") from None
        fields = _like_fresh(restored.state, _state_tree(abstract_state), state_sh if shardings is not None else None)
        state = abstract_state.replace(**fields)
        if host.get("replay_saved", True):
            replay = _like_fresh(restored.replay, abstract_state.replay,
                                 None if shardings is None else shardings.replay)
        elif fresh_replay is not None:
            replay = fresh_replay()
        else:
            raise CheckpointError(f"checkpoint {step} holds no replay buffer; pass fresh_replay to start an empty one")
        state = state.replace(replay=replay)
        if int(jax.device_get(state.iteration)) != step:
            raise CheckpointError(f"checkpoint {step} holds the state of iteration {int(state.iteration)}")
        return state, host

    def restore_latest(self, abstract_state, fresh_replay: Optional[Callable] = None, steps=None, shardings=None,
                       on_skip: Optional[Callable[[int, str], None]] = None):
        """``(TrainingState, host_state)`` of the latest checkpoint of ``steps`` (default: all on
        disk) that restores: one whose files do not (``CheckpointUnreadable``) is skipped for the
        one before it, and reported with ``on_skip(step, why)`` once an earlier one restored.
        Raises CheckpointError when none restores (one line: each checkpoint's reason), or at
        once when one does not match the run (an earlier one would not either). Reads only."""
        steps = sorted(self.steps() if steps is None else steps, reverse=True)
        if not steps:
            raise CheckpointError(f"no checkpoint in {self.directory}")
        skipped = []
        for step in steps:
            try:
                restored = self.restore(abstract_state, fresh_replay, step=step, shardings=shardings)
            except CheckpointUnreadable as e:
                skipped.append((step, str(e)))
                continue
            for s, why in skipped if on_skip is not None else ():
                on_skip(s, why)
            return restored
        reasons = [why for _, why in skipped]
        raise CheckpointError(f"no checkpoint in {self.directory} restores: " + "; ".join(reasons))

    def close(self) -> None:
        if self._manager is not None:
            self._manager.close()
            self._manager = None
