"""A training run's directory: its record (``config.json``, a ``RunRecord``), the lock that keeps
one process on it, and the steps that resume or extend it. Used by ``training.run`` and by the
entry points that read runs (``chain``, ``ship``, ``evaluate``, the experiments).

Layout of ``DIR``: ``config.json`` (this record), ``metrics.csv``, ``checkpoints/``
(``training.checkpointing``), the finished run's outputs (``FINAL_OUTPUTS``), TensorBoard events,
and, after an extension, ``before_extension_<budget>/`` with the outputs of the shorter run.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from typing import Optional

from training.cli import UsageError, write_json_atomic

CONFIG_JSON = "config.json"
# What a finished run writes (besides metrics.csv, events and checkpoints, which an extension continues).
FINAL_OUTPUTS = ("export.json", "export.npz", "new_skill.json", "new_skill.npz", "curves.png", "skill_usage.png",
                 "new_skill.mp4", "new_skill.gif")


@dataclasses.dataclass
class RunRecord:
    """The schema of a run's config.json: how it was started and the resolved ``TrainConfig``
    (``train_config``, a JSON object; ``config()`` reads it). Fields added since a run was started
    take the value that run had (``from_json``)."""

    command: str
    task: str
    physics: str
    skill_set: Optional[str]
    skill_source: str
    skill_dir: Optional[str]  # absolute path, or None
    skills: list  # the frozen skills' names (none from scratch)
    seed: int
    num_timesteps: int
    episode_length: Optional[int]
    checkpoint_every: Optional[int]
    replay_checkpoint: bool
    video: bool
    train_config: dict
    auto: list = dataclasses.field(default_factory=list)  # what resolve() chose, as logged
    # Batch sizes, updates per iteration and samples per env step of both learners
    # (parallel_skills.config.learner_schedule); None in records from before the field.
    learners: Optional[dict] = None
    extensions: list = dataclasses.field(default_factory=list)  # {"from", "to", "command"} per extension
    # What the same-seed numbers depend on besides the config (``host_facts``: on a CPU they are
    # reproducible per core count); None in records from before the field.
    host: Optional[dict] = None
    # The env's reset distribution (``RunConfig.start_states``); "table" in records from before it.
    start_states: str = "table"

    REQUIRED = ("task", "physics", "skills", "seed", "num_timesteps", "train_config")
    DEFAULTS = dict(command="", skill_set=None, skill_source="scripted", skill_dir=None, episode_length=None,
                    start_states="table",
                    checkpoint_every=None, replay_checkpoint=True, video=False)

    @classmethod
    def from_json(cls, data) -> "RunRecord":
        """ValueError (one line) for a record that lacks a required field or has a bad one."""
        if not isinstance(data, dict) or any(k not in data for k in cls.REQUIRED):
            raise ValueError(f"it lacks one of {', '.join(cls.REQUIRED)}")
        if not isinstance(data["train_config"], dict):
            raise ValueError("train_config is not an object")
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**dict(cls.DEFAULTS, **{k: v for k, v in data.items() if k in known}))

    def to_json(self) -> dict:
        data = dataclasses.asdict(self)
        if not self.extensions:  # (records of unextended runs have no such key)
            del data["extensions"]
        for optional in ("learners", "host"):
            if data[optional] is None:
                del data[optional]
        return data

    def config(self, where: str = CONFIG_JSON):
        """The recorded ``TrainConfig`` (checked as a config file is)."""
        return train_config_from_json(self.train_config, where)

    def env_overrides(self) -> dict:
        """The ``tasks.make`` keywords that rebuild the run's env (none for the task's defaults)."""
        out = {} if self.episode_length is None else {"episode_length": int(self.episode_length)}
        if self.start_states != "table":
            out["start_states"] = self.start_states
        return out


def train_config_from_json(data: dict, where: str):
    """The TrainConfig a run's config.json records. Fields added since a run was started take the
    value that run had: runs from before ``new_skill.num_critics`` existed trained one critic."""
    from parallel_skills.config import TrainConfig, from_dict

    try:
        return from_dict(TrainConfig(), recorded_train_config(data), where)
    except ValueError as e:
        raise UsageError(str(e)) from None


def host_facts() -> dict:
    """``{"cpu_cores", "backend", "devices", "processes", "jax"}`` of this process: the CPU cores it may
    run on (its affinity mask, which XLA's CPU thread pool follows), JAX's backend, device and process
    counts and version. Same-seed runs give the same numbers for equal facts."""
    import jax

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {"cpu_cores": int(cores), "backend": jax.default_backend(), "devices": int(jax.device_count()),
            "processes": int(jax.process_count()), "jax": jax.__version__}


def recorded_train_config(data: dict) -> dict:
    """A record's ``train_config`` object with the fields added since it was written at the value
    that run had (runs from before ``new_skill.num_critics`` trained one critic). A field removed
    since (docs/research/pruned.md) stays in it, and reading it as a config fails naming the field."""
    data = dict(data)
    if isinstance(data.get("new_skill"), dict) and "num_critics" not in data["new_skill"]:
        data["new_skill"] = dict(data["new_skill"], num_critics=1)
    return data


def config_path(out: str) -> str:
    return os.path.join(out, CONFIG_JSON)


def read_record(out: str, what: str = "cannot read the run") -> RunRecord:
    """The record of run directory ``out``; UsageError ``"<what>: <why>"`` if unreadable."""
    path = config_path(out)
    if not os.path.isfile(path):
        raise UsageError(f"{what}: {out} has no {CONFIG_JSON} (not a training.run directory)")
    try:
        with open(path) as f:
            return RunRecord.from_json(json.load(f))
    except (OSError, ValueError, TypeError) as e:
        raise UsageError(f"{what}: {path} is unreadable or invalid: {str(e).splitlines()[0]}") from None


def create(out: str, record: RunRecord) -> None:
    """Make the new run directory ``out`` and write its record."""
    try:
        os.makedirs(out)
    except OSError as e:
        raise UsageError(f"cannot create the run directory {out}: {e.strerror}") from None
    with open(config_path(out), "w") as f:
        json.dump(record.to_json(), f, indent=2, default=str)


# ----------------------------------------------------------------------------- one process per run

_LOCKS: dict = {}  # run directory -> its locked file descriptor (held while training)


def lock(out: str) -> None:
    """Lock the directory ``out`` exclusively (``flock``: released when the process ends, SIGKILL included),
    so that a second ``training.run`` on the same directory is refused instead of interleaving its
    checkpoints and metrics with the first's."""
    try:
        import fcntl
    except ImportError:  # (not POSIX: no lock)
        return
    key = os.path.abspath(out)
    if key in _LOCKS:
        return
    fd = os.open(out, os.O_RDONLY)  # the directory itself: nothing is written
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise UsageError(f"run directory {out} is in use by another training.run process; wait for it to end "
                         "or stop it, then --resume") from None
    _LOCKS[key] = fd


def unlock(out: str) -> None:
    fd = _LOCKS.pop(os.path.abspath(out), None)
    if fd is not None:
        os.close(fd)


# ----------------------------------------------------------------------------- finished runs, extensions

def exported_budget(out: str) -> Optional[int]:
    """The ``num_timesteps`` of ``out``'s export.json (the budget the run finished), None without one."""
    path = os.path.join(out, "export.json")
    if not os.path.exists(path):
        return None
    try:
        with open(path) as f:
            data = json.load(f)
        return int((data.get("metadata") or {}).get("num_timesteps", data["env_steps"]))
    except (OSError, ValueError, KeyError, TypeError):
        raise UsageError(f"cannot resume: {path} is unreadable; a run killed while exporting leaves no "
                         "export.json, so this one was changed by hand") from None


def archive_dir(out: str, budget: int) -> str:
    return os.path.join(out, f"before_extension_{budget}")


def extend(out: str, record: RunRecord, command: str) -> None:
    """Make ``out`` (config.json at a smaller budget, maybe finished) continue to ``record.num_timesteps``.

    Crash-safe in three idempotent steps: the finished run's outputs (``FINAL_OUTPUTS``) are copied
    to ``out/before_extension_<budget>/`` (a temporary directory renamed into place); config.json is
    rewritten with the new budget and an ``extensions`` entry; the outputs are removed, export.json
    last (until it goes, a resume sees an unfinished extension and redoes the steps).
    Training then continues from the latest checkpoint as an uninterrupted run of the larger budget
    would: the state at the old budget is the same (evaluations do not change it)."""
    with open(config_path(out)) as f:
        stored = json.load(f)
    old, new = int(stored["num_timesteps"]), int(record.num_timesteps)
    exported = exported_budget(out)
    if new == old and exported is None:
        return  # a plain resume
    if exported is not None:
        dst = archive_dir(out, exported)
        if not os.path.isdir(dst):
            tmp = dst + ".tmp"
            shutil.rmtree(tmp, ignore_errors=True)
            os.makedirs(tmp)
            for name in FINAL_OUTPUTS:
                if os.path.isfile(os.path.join(out, name)):
                    shutil.copy2(os.path.join(out, name), os.path.join(tmp, name))
            os.replace(tmp, dst)
    if new != old:
        stored["num_timesteps"] = new
        stored.setdefault("extensions", []).append({"from": old, "to": new, "command": command})
        record.extensions = stored["extensions"]
        write_json_atomic(config_path(out), stored, indent=2, default=str)
    for name in FINAL_OUTPUTS:
        if os.path.isfile(os.path.join(out, name)) and name != "export.json":
            os.remove(os.path.join(out, name))
    if exported is not None:
        os.remove(os.path.join(out, "export.json"))
    print(f"extending {out}: {old:,} -> {new:,} env steps"
          + (f"; its outputs at {exported:,} are kept in {archive_dir(out, exported)}" if exported else ""))


def new_skill_min_std(run_dir: str) -> float:
    """The new skill's std floor of the run in ``run_dir`` (its config.json's ``train_config.new_skill.min_std``),
    or ``NewSkillConfig.min_std`` when the directory holds no readable config.json."""
    from parallel_skills.config import NewSkillConfig

    try:
        with open(os.path.join(run_dir, "config.json")) as f:
            data = json.load(f)
        return float(data["train_config"]["new_skill"]["min_std"])
    except (OSError, ValueError, KeyError, TypeError):
        return float(NewSkillConfig.min_std)
