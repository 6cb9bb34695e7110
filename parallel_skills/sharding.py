"""Data parallelism over devices and hosts with JAX's own sharding (docs/design.md "Devices").

One 1-D mesh over all global devices (axis ``AXIS``). The jitted iteration is the single-device
program with sharding annotations; XLA's partitioner (GSPMD) splits it:

* the env batch: every per-env array of the actor state (env states, counters, running episode
  statistics) and the n-step window are sharded along their env axis, so each device steps
  num_envs / D envs;
* the learners: each sampled batch is sharded along its rows (each device computes the losses and
  gradients of batch / D rows; the partitioner sums the gradients across devices) and the
  parameters, optimiser states and target networks are replicated;
* the replay is replicated: each iteration's transitions are gathered to every device (T · B rows,
  small next to one learner batch's work) and each device samples its rows of the global batch
  from the same indices. This is a deliberate alternative to per-device buffers: the run is then
  the same computation for every device count (the same rows sampled, the same random numbers:
  JAX's partitionable threefry), so a run on D devices matches the one-device run up to the order
  of float sums in the cross-device gradient reduction, and a checkpoint restores on any mesh.
  Its cost is the buffer's memory on every device (≈ 0.4 KB per row on manipulation tasks: 0.4 GB
  for the default 10⁶ rows).

Multi-host (``jax.distributed``): the same program runs in every process on global arrays;
``initialize`` connects the processes, process 0 alone writes the run directory (checkpoints are
written by all, through orbax's multi-process support).
"""

from __future__ import annotations

import dataclasses
from typing import Optional, Sequence

import jax
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

AXIS = "data"
DEFAULT_TIMEOUT_SECONDS = 300


def make_mesh(devices: Optional[Sequence] = None) -> Mesh:
    """A 1-D mesh (axis ``AXIS``) over ``devices`` (default: every global device, all processes)."""
    devices = list(jax.devices() if devices is None else devices)
    import numpy as np

    return Mesh(np.array(devices), (AXIS,))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P())


def check_divisible(config, num_devices: int) -> None:
    """ValueError (one line) unless the env batch and both learner batches divide by ``num_devices``."""
    if num_devices <= 1:
        return
    sizes = {"num_envs": config.num_envs, "scheduler.batch_size": config.scheduler.batch_size,
             "new_skill.batch_size": config.new_skill.batch_size}
    for name, n in sizes.items():
        if n is not None and int(n) % num_devices:
            raise ValueError(f"{name} {n} does not divide by the {num_devices} devices: use a multiple of "
                             f"{num_devices} (each device takes an equal share)")


def _split(mesh: Mesh, axis: int) -> NamedSharding:
    """Split along ``axis`` over the mesh."""
    return NamedSharding(mesh, P(*([None] * axis + [AXIS])))


def _along(leaf, mesh: Mesh, axis: int, size: int) -> NamedSharding:
    """Sharded along ``axis`` when that axis has ``size`` entries (the env batch), else replicated."""
    shape = getattr(leaf, "shape", ())
    return _split(mesh, axis) if len(shape) > axis and shape[axis] == size else replicated(mesh)


def state_shardings(state, mesh: Mesh, num_envs: int, seed_axis: bool = False):
    """NamedShardings for a ``TrainingState`` (or its abstract shapes): the actor state sharded along
    its env axis (axis 0; ``pending`` [n − 1, B, ...]: axis 1), everything else replicated.
    ``seed_axis``: the state is batched over seeds (``train_seeds``), every env axis one further."""
    lead = 1 if seed_axis else 0
    rep = replicated(mesh)
    fields = {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}
    out = {name: jax.tree.map(lambda _: rep, value) for name, value in fields.items()}
    out["actor"] = jax.tree.map(lambda x: _along(x, mesh, lead, num_envs), fields["actor"])
    if fields.get("pending") is not None:
        out["pending"] = jax.tree.map(lambda x: _along(x, mesh, lead + 1, num_envs), fields["pending"])
    return state.replace(**out)


def constrain(tree, mesh: Mesh, size: int, axis: int = 0):
    """Inside a jitted function: constrain the leaves with ``size`` entries on ``axis`` to be split
    along the mesh (the actor state: ``size`` = num_envs; a learner batch: ``size`` = its rows, each
    device computing the losses of its rows). Other leaves are left to the partitioner."""
    def one(x):
        if getattr(x, "ndim", 0) > axis and x.shape[axis] == size:
            return jax.lax.with_sharding_constraint(x, _split(mesh, axis))
        return x

    return jax.tree.map(one, tree)


def put(tree, shardings):
    """``tree`` (host or single-device arrays, the same in every process) placed as global arrays
    with ``shardings``; works across processes (each places its addressable shards)."""
    import numpy as np

    def one(x, s):
        x = np.asarray(x) if not isinstance(x, jax.Array) or x.is_fully_addressable else x
        if isinstance(x, np.ndarray):
            return jax.make_array_from_callback(x.shape, s, lambda idx: x[idx])
        return jax.device_put(x, s)

    return jax.tree.map(one, tree, shardings)


def wait_for_coordinator(coordinator: str, timeout_seconds: float) -> None:
    """Return once ``coordinator`` (HOST:PORT) accepts TCP connections; ValueError (one line) if it
    does not within ``timeout_seconds`` (process 0 starts its coordination service only when it
    reaches ``initialize``, so the other processes may have to wait for it)."""
    import socket
    import time

    host, _, port = coordinator.rpartition(":")
    deadline = time.monotonic() + float(timeout_seconds)
    why = "no answer"
    while True:
        try:
            with socket.create_connection((host.strip("[]"), int(port)), timeout=1.0):
                return
        except socket.gaierror as e:
            raise ValueError(f"coordinator {coordinator}: unknown host {host!r} ({e.strerror})") from None
        except OSError as e:
            why = e.strerror or type(e).__name__
        if time.monotonic() >= deadline:
            raise ValueError(f"coordinator {coordinator} unreachable: no answer within {timeout_seconds} s "
                             f"({why}); is process 0 running with the same --coordinator?")
        time.sleep(0.25)


@dataclasses.dataclass(frozen=True)
class Distributed:
    """Where this process stands in a multi-process run (``jax.distributed``)."""

    process_id: int = 0
    num_processes: int = 1

    @property
    def primary(self) -> bool:
        return self.process_id == 0


def agreed(flag: bool) -> bool:
    """Process 0's ``flag`` in every process (itself with one process). A host-side decision that
    leads to collectives (a checkpoint: orbax saves through every process) must be the same in
    all of them; one taken from each process's own wall clock is not."""
    if jax.process_count() == 1:
        return bool(flag)
    import numpy as np
    from jax.experimental import multihost_utils

    return bool(multihost_utils.broadcast_one_to_all(np.int32(bool(flag))))


def initialize(coordinator: Optional[str] = None, num_processes: Optional[int] = None,
               process_id: Optional[int] = None, timeout_seconds: int = DEFAULT_TIMEOUT_SECONDS,
               auto: bool = False) -> Distributed:
    """Connect this process to the others (``jax.distributed.initialize``) before any device is
    used: with ``coordinator`` (HOST:PORT of process 0), ``num_processes`` and ``process_id``, or
    (``auto``) from the cluster's environment, which JAX reads itself (SLURM, Open MPI, ...;
    given values override it). Nothing given: one process, nothing done. On a CPU the processes
    reduce through gloo. ValueError (one line) for inputs out of range or a coordinator that does
    not answer within ``timeout_seconds``."""
    if coordinator is None and num_processes is None and process_id is None and not auto:
        return Distributed()
    if num_processes is not None and num_processes < 1:
        raise ValueError(f"num_processes must be a positive integer, got {num_processes}")
    if process_id is not None and num_processes is not None and not 0 <= process_id < num_processes:
        raise ValueError(f"process_id {process_id} is out of range: use 0 .. {num_processes - 1} for "
                         f"{num_processes} processes")
    if coordinator is not None:
        host, sep, port = coordinator.rpartition(":")
        if not sep or not host or not port.isdigit():
            raise ValueError(f"coordinator {coordinator!r} must be HOST:PORT")
        if not auto and (num_processes is None or process_id is None):
            raise ValueError("--coordinator needs --num_processes and --process_id")
    elif not auto:
        raise ValueError("--num_processes / --process_id need --coordinator HOST:PORT (or --distributed: "
                         "the cluster's environment)")
    if timeout_seconds < 1:
        raise ValueError(f"the coordinator timeout must be at least 1 s, got {timeout_seconds}")
    if coordinator is not None and process_id not in (None, 0):
        # JAX aborts the whole process (a fatal C++ error, not an exception) when the coordinator
        # does not answer in time: find out first, and fail with one line.
        wait_for_coordinator(coordinator, timeout_seconds)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # (ignored by GPU / TPU backends)
    try:
        jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                                   process_id=process_id, initialization_timeout=int(timeout_seconds))
    except Exception as e:  # noqa: BLE001 - jax raises several types (XlaRuntimeError, RuntimeError, ValueError)
        first = (str(e).strip().splitlines() or [""])[0]
        if auto and coordinator is None and "coordinator_address" in first:
            raise ValueError("--distributed found no cluster in the environment (SLURM, Open MPI, ... as JAX "
                             "detects them): give --coordinator HOST:PORT --num_processes N --process_id I") from None
        raise ValueError(f"jax.distributed could not connect to coordinator {coordinator} as process "
                         f"{process_id} of {num_processes} within {timeout_seconds} s ({type(e).__name__}: "
                         f"{first[:160]})") from None
    return Distributed(process_id=jax.process_index(), num_processes=jax.process_count())
