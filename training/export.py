"""Export a trained run: ``DIR/export.npz`` + ``DIR/export.json`` (issue #5, item 4).

    from training.export import write_export
    make_policy, params, metrics = parallel_skills.train(env, skills, ..., config=cfg)
    path = write_export(run_dir, params, env=env, config=resolved_cfg, task="lift", physics="kinematic",
                        metadata={"skills": names, "seed": 0, "env_steps": metrics["env_steps"],
                                  "command": "...", "success": metrics["eval/new_skill_success"]})

Evaluate it with ``python -m training.evaluate --policy DIR/export.npz`` (the new skill alone) or
``--policy DIR/export.npz:scheduler`` (the scheduler sequencing the recorded skills); load it
without JAX with ``parallel_skills.numpy_policy.load_export``.

``export.npz`` holds two sections, each in the ``Skill.save`` layout (flax leaves under
``policy/params/...`` plus the run's observation statistics ``obs_mean`` / ``obs_std``, which the
network applies as clip((obs - mean) / std, ±10) before its torso):

* ``new_skill/...``: the Gaussian-MLP new skill (torso ``dense_n``, ``layer_norm``, ``head`` of
  size 2·A: mean, raw std);
* ``scheduler/...``: the scheduler policy (torso, ``head_i`` of size N+1, ``head_k`` of size M).

``export.json``: ``format`` / ``version``, ``task``, ``physics``, ``obs_size``, ``action_size``,
``seed``, ``env_steps``, ``method``, ``new_skill`` {name, hidden, action_size, min_std},
``scheduler`` {hidden, num_skills (N+1), skill_lengths (K), skill_names (the N frozen skills in
scheduler index order, then the new skill), new_skill_index (N)}, ``metadata`` (the rest;
``training.run`` records ``skill_sources``: where each frozen skill came from, scripted controller,
shipped library or ``--skill_dir`` file with its SHA-256, so that ``:scheduler`` runs the same skills).
"""

from __future__ import annotations

import json
import os
import tempfile

import numpy as np

from parallel_skills.numpy_policy import EXPORT_FORMAT, EXPORT_VERSION, NumpyExport

NPZ, JSON = "export.npz", "export.json"
REQUIRED_METADATA = ("skills", "seed", "env_steps")


def file_sha256(path: str) -> str:
    """Hex SHA-256 of a file's bytes (records which skill file an export's scheduler ran)."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class ExportExistsError(FileExistsError, ValueError):
    """The run directory already holds an export (exports are never overwritten)."""


def _section(policy_params, stats) -> dict:
    """{"policy": flax variables, "obs_mean", "obs_std"} flattened as ``Skill.save`` does."""
    from parallel_skills.skills import GaussianSkillParams, flatten_params

    return flatten_params(GaussianSkillParams.from_normalizer(policy_params, stats).as_dict())


def _hidden(flat: dict) -> list[int]:
    n = 0
    while f"policy/params/torso/dense_{n}/kernel" in flat:
        n += 1
    return [int(flat[f"policy/params/torso/dense_{j}/kernel"].shape[-1]) for j in range(n)]


def _json_default(o):
    if isinstance(o, np.generic) or (isinstance(o, np.ndarray) and o.ndim == 0):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _commit(tmp: str, final: str) -> None:
    """Move ``tmp`` to ``final`` atomically, never replacing an existing ``final``."""
    try:
        os.link(tmp, final)  # fails if final exists: no clobbering even in a race
    except FileExistsError:
        raise ExportExistsError(f"{final} already exists; exports are never overwritten") from None
    except OSError:  # file systems without hard links
        if os.path.exists(final):
            raise ExportExistsError(f"{final} already exists; exports are never overwritten") from None
        os.replace(tmp, final)
        return
    os.unlink(tmp)


def _write_tmp(out_dir: str, write) -> str:
    fd, tmp = tempfile.mkstemp(dir=out_dir, prefix=".export-", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        os.unlink(tmp)
        raise
    return tmp


def write_export(out_dir, params, *, env, config, task, physics, metadata) -> str:
    """Write ``out_dir/export.npz`` + ``out_dir/export.json``; return the .npz path.

    params: what ``parallel_skills.train`` returns (``train.TrainedParams``).
    env: the trained env (``observation_size``, ``action_size``). config: the run's *resolved*
    ``TrainConfig`` (hidden sizes, skill lengths K, min_std, method; checked against ``params``).
    task, physics: names recorded for the evaluator. metadata: a JSON-able dict that must hold
    ``skills`` (the N frozen skill names in the order given to ``train``), ``seed`` and
    ``env_steps``; any other keys (command, success, ...) are stored under ``metadata``.

    Both files are written to temporary files in ``out_dir`` and then moved into place (the JSON
    last); an existing export is never overwritten (``ExportExistsError``, a ``FileExistsError``
    and ``ValueError``). Other bad arguments raise ``ValueError``. ``out_dir`` is created if missing.
    """
    missing = [k for k in REQUIRED_METADATA if k not in metadata]
    if missing:
        raise ValueError(f"write_export metadata lacks {missing}; it needs {list(REQUIRED_METADATA)}")
    meta = dict(metadata)
    skills = [str(s) for s in meta.pop("skills")]
    seed, env_steps = int(meta.pop("seed")), int(meta.pop("env_steps"))
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    sc, nc = config.scheduler, config.new_skill

    new = _section(params.new_skill, params.normalizer)
    sched = _section(params.scheduler, params.normalizer)
    for name, flat, hidden in (("new_skill", new, nc.hidden), ("scheduler", sched, sc.hidden)):
        if _hidden(flat) != [int(h) for h in hidden]:
            raise ValueError(f"{name} parameters have hidden sizes {_hidden(flat)}, the config says {list(hidden)}")
    head_i = sched.get("policy/params/head_i/bias")
    if head_i is None or head_i.shape[0] != len(skills) + 1:
        raise ValueError(f"metadata['skills'] names {len(skills)} frozen skills, but the scheduler chooses among "
                         f"{None if head_i is None else head_i.shape[0]} (it must be N + 1, the new skill last)")
    new_name = f"{task}_new_skill"
    header = {
        "format": EXPORT_FORMAT, "version": EXPORT_VERSION, "task": task, "physics": physics,
        "obs_size": obs_size, "action_size": action_size, "seed": seed, "env_steps": env_steps,
        "method": getattr(config, "method", "skills"),
        "new_skill": {"name": new_name, "hidden": [int(h) for h in nc.hidden], "action_size": action_size,
                      "obs_size": obs_size, "min_std": float(nc.min_std)},
        "scheduler": {"hidden": [int(h) for h in sc.hidden], "num_skills": len(skills) + 1,
                      "skill_lengths": [int(k) for k in sc.skill_lengths], "skill_names": skills + [new_name],
                      "new_skill_index": len(skills)},
        "metadata": meta,
    }
    arrays = {f"new_skill/{k}": v for k, v in new.items()}
    arrays.update({f"scheduler/{k}": v for k, v in sched.items()})
    text = json.dumps(header, indent=2, sort_keys=True, default=_json_default)
    # Validate exactly what a reader will check (sizes, array shapes) before writing anything.
    NumpyExport(os.path.join(str(out_dir), NPZ), arrays, json.loads(text))

    out_dir = str(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    npz_path, json_path = os.path.join(out_dir, NPZ), os.path.join(out_dir, JSON)
    for path in (npz_path, json_path):
        if os.path.exists(path):
            raise ExportExistsError(f"{path} already exists; exports are never overwritten")
    tmps: list[str] = []
    try:
        tmps.append(_write_tmp(out_dir, lambda f: np.savez(f, **arrays)))
        tmps.append(_write_tmp(out_dir, lambda f: f.write(text.encode())))
        _commit(tmps[0], npz_path)
        try:
            _commit(tmps[1], json_path)
        except BaseException:
            os.unlink(npz_path)  # ours: moved into place just above
            raise
    finally:
        for tmp in tmps:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return npz_path
