"""The files of a training.run run directory while it trains and after: the metrics.csv /
TensorBoard / checkpoint sink (``RunFiles``, what ``parallel_skills.train`` calls back), the resume
surgery (``restore_run`` / ``restore_group`` read a checkpoint, ``resume_files`` then cuts
metrics.csv back to it and sets aside what it does not cover), a finished or stopped run read back
for analysis (``load_checkpointed_run``) and the finished run's outputs
(``write_outputs``: new_skill.npz, plots, video, export). ``training.run`` parses and
orchestrates; nothing here parses flags.
"""

from __future__ import annotations

import csv
import io
import json
import os
import sys
from typing import Any, NamedTuple, Optional

from parallel_skills import methods
from training import rundir
from training.cli import UsageError
from training.logging_utils import TensorBoardLogger, format_row, release_free_memory, resident_mb

CSV_FIELDS = ["env_steps", "wall_time", "eval/new_skill_success", "eval/new_skill_return", "eval/scheduler_success",
              "eval/scheduler_return", "episode_success", "episode_return", "new_skill_selection_rate",
              "scheduler/critic_loss", "new_skill/critic_loss", "scheduler/policy_entropy_i", "skill_histogram",
              "length_histogram", "skill_steps", "skill_runs", "scheduler/q_mean", "new_skill/q_mean",
              "new_skill/crr_weight_mean", "new_skill/policy_log_std_mean", "rss_mb",
              # Scheduler diagnostics (docs/research/scheduler.md): as it collects, its decisions, its replay.
              "eval/scheduler_sampled_success", "eval/scheduler_sampled_return", "eval/scheduler_discounted_return",
              "eval/scheduler_value_at_reset", "decision_entropy_i", "decision_entropy_k", "skill_share",
              "length_share", "replay_rewarded_fraction", "scheduler/policy_entropy_k",
              # The new skill alone with actions sampled from its Gaussian (as it collects).
              "eval/new_skill_sampled_success", "eval/new_skill_sampled_return",
              # The new skill alone, each action the best of the mean and samples by its critic.
              "eval/new_skill_critic_weighted_success", "eval/new_skill_critic_weighted_return",
              # The greedy scheduler with the new skill's sampled actions (its mean: eval/scheduler_*).
              "eval/scheduler_new_skill_sampled_success", "eval/scheduler_new_skill_sampled_return",
              # With NewSkillConfig.policy_ema > 0 the new skill evaluated above is its moving average
              # (what is exported); its online policy, mean actions, on the same episodes.
              "eval/new_skill_online_success", "eval/new_skill_online_return"]


# Without --checkpoint_every: checkpoint at evaluations, but at most once a minute (a lift run on a
# CPU evaluates every ~10 s; a checkpoint with its replay takes ~1 s there).
CHECKPOINT_MIN_SECONDS = 60.0


def csv_header(path):
    with open(path, newline="") as f:
        return next(csv.reader(f), None)


def write_plots(out):
    """DIR/curves.png and DIR/skill_usage.png; a failure is reported, not fatal (the run is saved)."""
    try:
        from training.plot import write_run_plots

        paths = write_run_plots(out)
    except ImportError as e:
        print(f"plots skipped: {e} (pip install 'parallel-skills[plots]')", file=sys.stderr)
    except Exception as e:  # noqa: BLE001 - plots are a by-product: never lose a finished run to them
        print(f"plots skipped: {type(e).__name__}: {e}", file=sys.stderr)
    else:
        print(f"plots saved: {', '.join(paths)}")


def write_video(out, env, make_policy, params, seed, episode_length):
    """DIR/new_skill.mp4 (or .gif): one episode of the new skill alone; failures are reported."""
    import jax

    from training.video import VideoError, record_policy

    try:
        path = record_policy(env, make_policy(params, "new_skill"), os.path.join(out, "new_skill"),
                             key=jax.random.PRNGKey(seed + 20_000), episode_length=episode_length)
    except VideoError as e:
        print(f"video skipped: {e}", file=sys.stderr)
    except Exception as e:  # noqa: BLE001 - as for plots: the trained run is what matters
        print(f"video skipped: {type(e).__name__}: {e}", file=sys.stderr)
    else:
        print(f"video saved: {path}")


def skill_sources(skills, physics: str) -> list[dict]:
    """Where each frozen skill came from, for the export (``training.evaluate ...:scheduler`` runs the
    same skills): ``{"name", "source": "scripted"}``; ``{"name", "source": "library", "library":
    checkpoints/ subdirectory, "sha256"}`` (no machine path: resolved in the repository at
    evaluation); ``{"name", "source": "skill_dir", "path": as given, "sha256"}``."""
    from training.skill_library import library_dir
    from training.export import file_sha256

    out = []
    for s in skills:
        src = s.metadata.get("source", "scripted")
        entry = {"name": s.name, "source": src}
        if src == "library":
            entry.update(library=library_dir(physics), sha256=file_sha256(s.metadata["path"]))
        elif src == "skill_dir":
            entry.update(path=s.metadata["path"], sha256=file_sha256(s.metadata["path"]))
        out.append(entry)
    return out


def restore_target(env, skills, resolved, seed: int, mesh=None) -> dict:
    """What a checkpoint of a run of ``env``, ``skills`` and the resolved config restores into: the
    keyword arguments of ``Checkpointer.restore`` / ``restore_latest`` (the state's structure, the
    empty replay of a checkpoint without one and, with a ``mesh``, each leaf's sharding on it, so
    that each process reads its own shards)."""
    from training.checkpointing import abstract_training_state

    abstract, fresh_replay = abstract_training_state(env, skills, resolved, seed)
    shardings = None
    if mesh is not None:
        from parallel_skills.sharding import state_shardings

        shardings = state_shardings(abstract, mesh, resolved.num_envs)
    return dict(abstract_state=abstract, fresh_replay=fresh_replay, shardings=shardings)


def restore_state(ckpt, env, skills, resolved, seed: int, steps=None, mesh=None, on_skip=None):
    """``(TrainingState, host state)`` of the latest of checkpoints ``steps`` (default: all) of
    ``ckpt`` that restores (``restore_target``); read only. The checkpoint reader of resume and of
    the read-outs of a run (``load_checkpointed_run``). CheckpointError when none restores."""
    return ckpt.restore_latest(steps=steps, on_skip=on_skip, **restore_target(env, skills, resolved, seed, mesh))


def restore_run(out, ckpt, csv_path, env, skills, resolved, seed: int, steps=None, mesh=None, primary: bool = True):
    """The checkpointed (state, host state) of a resumed run (``restore_state``), an unreadable
    later checkpoint reported in one line on stderr; read only (``resume_files`` then updates the
    run directory, on the primary process alone)."""
    from training.checkpointing import CheckpointError

    try:
        state, host = restore_state(ckpt, env, skills, resolved, seed, steps, mesh,
                                    on_skip=report_skipped if primary else None)
    except CheckpointError as e:
        raise UsageError(f"cannot resume: {e}") from None
    return state, checked_host(ckpt, csv_path, host, primary)


class CheckpointedRun(NamedTuple):
    """A run directory read back from its record and one checkpoint (``load_checkpointed_run``)."""
    record: Any  # rundir.RunRecord
    config: Any  # the run's resolved TrainConfig
    env: Any
    skills: Any  # the frozen skills the run trained with (skill_library.load_skills)
    state: Any  # TrainingState
    host: dict  # the checkpoint's host state (env_steps, csv_bytes, ...)

    def trainer(self):
        """The run's trainer (``parallel_skills.train.make_trainer``): its networks and evaluators."""
        from parallel_skills.train import make_trainer

        return make_trainer(self.env, self.skills, self.config)


def load_checkpointed_run(run_dir: str, step: Optional[int] = None) -> CheckpointedRun:
    """The run in ``run_dir`` rebuilt from its config.json (env, skills, resolved config) and its
    checkpoint ``step`` (default: the latest that restores; ``restore_state``). Reads only.
    UsageError (one line) when ``run_dir`` is not a run, or no such checkpoint restores."""
    import tasks
    from training import skill_library
    from training.checkpointing import CheckpointError, Checkpointer

    record = rundir.read_record(run_dir, "cannot read the run")
    resolved = record.config(f"{rundir.config_path(run_dir)} train_config")
    env = tasks.make(record.task, physics=record.physics, **record.env_overrides())
    skills = skill_library.load_skills(list(record.skills), record.physics, record.skill_source,
                                       env.observation_size, env.action_size, skill_dir=record.skill_dir)
    ckpt = Checkpointer(run_dir)
    if step is not None and int(step) not in ckpt.steps():
        raise UsageError(f"{run_dir}: no checkpoint at iteration {int(step)} (it has: "
                         f"{', '.join(map(str, ckpt.steps())) or 'none'})")
    try:
        state, host = restore_state(ckpt, env, skills, resolved, int(record.seed),
                                    steps=None if step is None else [int(step)])
    except CheckpointError as e:
        raise UsageError(f"{run_dir}: {e}") from None
    return CheckpointedRun(record, resolved, env, skills, state, host)


def checked_host(ckpt, csv_path, host, primary: bool = True) -> dict:
    """``host`` of a restored checkpoint, once it is known to be training.run's and (primary
    process) its metrics.csv to hold the rows it covers; UsageError otherwise."""
    if not all(k in host for k in ("csv_bytes", "csv_rows", "env_steps")):
        raise UsageError(f"cannot resume: the checkpoint in {ckpt.directory} was not written by training.run")
    if not primary:
        return host
    size = os.path.getsize(csv_path) if os.path.isfile(csv_path) else -1
    if size < int(host["csv_bytes"]):
        raise UsageError(f"cannot resume: {csv_path} is {'missing' if size < 0 else f'{size} bytes'}, "
                         f"the checkpoint covers its first {host['csv_bytes']} bytes")
    return host


def report_skipped(step: int, why: str):
    print(f"warning: {why}; resuming from the checkpoint before it", file=sys.stderr, flush=True)


def resume_files(out, csv_path, host, run=None, extend_command=None):
    """After a successful restore (nothing is written before one): record an extension
    (``rundir.extend``: config.json, the finished outputs kept in before_extension_N) when
    ``extend_command`` is given, then cut metrics.csv back to the rows the checkpoint covers and
    remove a half-written export."""
    if extend_command is not None:
        rundir.extend(out, run, extend_command)
    set_aside = set_aside_later_checkpoints(out, int(host["iteration"]))
    with open(csv_path, "r+b") as f:  # drop the rows written after the checkpoint
        f.truncate(int(host["csv_bytes"]))
    stale = os.path.join(out, "export.npz")  # an export killed before its export.json: redone at the end
    if os.path.exists(stale):
        os.remove(stale)
    print(f"resuming {out} from its checkpoint at iteration {host['iteration']} "
          f"({host['env_steps']:,} env steps, {host['csv_rows']} metrics rows)"
          + ("" if host.get("replay_saved", True) else "; the checkpoint holds no replay: "
             "the buffer starts empty")
          + (f"; the later checkpoints that do not restore moved to {os.path.dirname(set_aside[0])}" if set_aside
             else ""))


UNRESTORABLE_DIR = "unrestorable_checkpoints"  # OUT/<this>/<iteration>: checkpoints a resume skipped


def set_aside_later_checkpoints(out, iteration: int) -> list:
    """Move the checkpoints after ``iteration`` (those a resume found unreadable and skipped, or a
    --seeds run's beyond the group's common one) out of OUT/checkpoints into OUT/unrestorable_checkpoints
    (kept, not deleted): the resumed run writes those iterations again, and orbax saves no iteration
    at or below its latest. Returns their new paths."""
    from training.checkpointing import CHECKPOINT_SUBDIR

    src = os.path.join(out, CHECKPOINT_SUBDIR)
    names = os.listdir(src) if os.path.isdir(src) else []
    later = sorted(int(n) for n in names if n.isdigit() and int(n) > iteration)
    moved = []
    for step in later:
        dest = os.path.join(out, UNRESTORABLE_DIR, str(step))
        n = 1
        while os.path.exists(dest):
            dest, n = os.path.join(out, UNRESTORABLE_DIR, f"{step}.{n}"), n + 1
        os.makedirs(os.path.dirname(dest), exist_ok=True)
        os.rename(os.path.join(src, str(step)), dest)
        moved.append(dest)
    return moved


def save_new_skill(path, run, resolved, env, params, **metadata):
    """The run's new skill in ``params`` (``TrainedParams``) as a loadable Gaussian-MLP skill file
    ``path`` + .json: sizes, task, physics, seed, command, the skills it trained with and ``metadata``."""
    from parallel_skills import Skill

    skill = Skill.gaussian_mlp(f"{run.task}_new_skill", params.new_skill_params(), env.action_size,
                               resolved.new_skill.hidden)
    skill.save(path, obs_size=int(env.observation_size), task=run.task, physics=run.physics, seed=int(run.seed),
               command=run.command, trained_with=list(run.skills), **metadata)


BEST_NEW_SKILL = "best_new_skill.npz"  # the new skill at its best evaluation so far (``RunFiles.policy_params``)


def best_recorded(out) -> float:
    """``eval/new_skill_success`` of the run's ``best_new_skill.json`` (-inf when there is none)."""
    path = os.path.join(out, BEST_NEW_SKILL[:-4] + ".json")
    try:
        with open(path) as f:
            return float(json.load(f)["success"])
    except (OSError, ValueError, KeyError, TypeError):
        return float("-inf")


class RunFiles:
    """One run directory's files while it trains: metrics.csv rows, TensorBoard events,
    checkpoints and the best evaluated new skill (``progress``, ``checkpoint`` and ``policy_params``
    are what ``train`` calls back)."""

    def __init__(self, out, run, resolved, resume: bool, host_state, bar, prefix: str = "", primary: bool = True,
                 env=None):
        from training.checkpointing import Checkpointer

        self.out, self.bar, self.prefix, self.primary = out, bar, prefix, primary
        self.run, self.resolved, self.env = run, resolved, env
        # (A resume re-runs the evaluations after its checkpoint exactly: the file it finds is theirs.)
        self.best = best_recorded(out) if resume else float("-inf")
        self.ckpt = Checkpointer(out, save_replay=run.replay_checkpoint)
        csv_path = os.path.join(out, "metrics.csv")
        start_steps = int(host_state["env_steps"]) if host_state else 0
        self.csv_rows = int(host_state["csv_rows"]) if host_state else 0
        self.f = self.tb = None
        if not primary:  # another process of a multi-process run: checkpoints only (orbax writes them together)
            return
        # A resumed run keeps the columns its metrics.csv was started with (runs from older versions).
        header = csv_header(csv_path) if resume else None
        self.fields = header or CSV_FIELDS
        # TensorBoard: a resume opens a new event file that purges the steps past the checkpoint.
        self.tb = TensorBoardLogger(out, list(run.skills), resolved.scheduler.skill_lengths,
                                    purge_step=start_steps + 1 if resume else None)
        self.f = open(csv_path, "ab" if resume else "wb")
        if not header:
            self._write_row(self.fields)

    def _write_row(self, row):
        buf = io.StringIO()
        csv.writer(buf).writerow(row)
        self.f.write(buf.getvalue().encode())
        self.f.flush()

    def progress(self, steps, m):
        if not self.primary:
            return
        release_free_memory()  # (freed compiler memory glibc would keep: rss_mb then tracks live memory)
        m = dict(m, rss_mb=resident_mb())
        self._write_row(format_row(m, self.fields))
        self.csv_rows += 1
        self.tb.log(steps, m)
        self.bar.update(steps, m, self.prefix)

    def policy_params(self, steps, params, m):
        """Keep the new skill of the best evaluation so far (ties: the later one) as
        ``best_new_skill.npz`` + .json, beside the last one (``new_skill.npz``, written at the end)."""
        success = float(m.get("eval/new_skill_success", float("nan")))
        if not self.primary or self.env is None or not success >= self.best:
            return
        self.best = success
        save_new_skill(os.path.join(self.out, BEST_NEW_SKILL), self.run, self.resolved, self.env, params,
                       success=success, env_steps=int(steps),
                       eval_return=float(m.get("eval/new_skill_return", 0.0)),
                       selected="best evaluation so far (eval/new_skill_success, ties: later)")

    def checkpoint(self, state, host):
        if not self.primary:  # (orbax writes the host JSON from the primary process only)
            self.ckpt.save(state, dict(host, csv_bytes=0, csv_rows=0))
            return
        os.fsync(self.f.fileno())  # the rows this checkpoint covers are on disk first
        self.ckpt.save(state, dict(host, csv_bytes=self.f.tell(), csv_rows=self.csv_rows))

    def close(self):
        if self.f is not None:
            self.f.close()
            self.tb.close()
        self.ckpt.close()


def params_digest(params) -> str:
    """sha256 of the trained parameters (this process's copy of every replicated array)."""
    import hashlib

    import jax
    import numpy as np

    h = hashlib.sha256()
    for leaf in jax.tree.leaves(jax.device_get(params)):
        h.update(np.ascontiguousarray(leaf).tobytes())
    return h.hexdigest()[:16]


def common_steps(ckpts, outs) -> list:
    """The checkpoint iterations all runs of a ``--seeds`` group have, latest first (they save
    together; a process killed between two of their saves leaves the last one behind in some)."""
    common = set.intersection(*(set(c.steps()) for c in ckpts))
    if not common:
        raise UsageError(f"cannot resume: the runs of {os.path.dirname(outs[0])} share no checkpoint iteration "
                         "(resume them one by one: --resume --out DIR/sSEED)")
    return sorted(common, reverse=True)


def restore_group(outs, ckpts, runs, env, skills, resolved, mesh=None):
    """The (state, host) of every run of a ``--seeds`` group at their latest common checkpoint that
    restores in all of them (an unreadable one in any run: the one before, reported on stderr)."""
    from training.checkpointing import CheckpointError, CheckpointUnreadable

    steps = common_steps(ckpts, outs)
    reasons = []
    for step in steps:
        try:
            restored = []
            for out, c, r in zip(outs, ckpts, runs):
                state, host = c.restore(step=step, **restore_target(env, skills, resolved, int(r.seed), mesh))
                restored.append((state, checked_host(c, os.path.join(out, "metrics.csv"), host)))
        except CheckpointUnreadable as e:
            reasons.append((step, str(e)))
            continue
        except CheckpointError as e:
            raise UsageError(f"cannot resume: {e}") from None
        for s, why in reasons:
            report_skipped(s, why)
        return restored
    raise UsageError("cannot resume: no common checkpoint of the group restores: "
                     + "; ".join(why for _, why in reasons))


def write_outputs(out, run, resolved, env, skills, make_policy, params, metrics, video: bool, seconds: float):
    """The finished run's new skill (``new_skill.npz``), plots, video and ``export.npz``."""
    from training.export import write_export

    names, seed, num_timesteps = list(run.skills), int(run.seed), int(run.num_timesteps)
    save_new_skill(os.path.join(out, "new_skill.npz"), run, resolved, env, params,
                   success=metrics["eval/new_skill_success"], env_steps=metrics["env_steps"])
    print(f"new skill saved: {os.path.join(out, 'new_skill.npz')}  ({metrics['env_steps']:,} env steps, "
          f"{seconds:.0f} s)")
    write_plots(out)
    if video:
        write_video(out, env, make_policy, params, seed, int(run.episode_length or 0) or None)
    # The export's scheduler chooses among the frozen skills: none for finetune, whose one skill is
    # where the new skill started (recorded as finetuned_from).
    starts_from_skill = methods.get(resolved.method).starts_from_skill
    frozen = [] if starts_from_skill else list(skills)
    meta = {"skills": [s.name for s in frozen], "skill_sources": skill_sources(frozen, run.physics), "seed": seed,
            "env_steps": metrics["env_steps"], "command": run.command,
            "skill_set": run.skill_set, "num_timesteps": num_timesteps,
            "success": metrics["eval/new_skill_success"], "return": metrics["eval/new_skill_return"]}
    if starts_from_skill:
        meta["finetuned_from"] = names
    if run.extensions:
        meta["extensions"] = run.extensions
    for k in ("eval/scheduler_success", "eval/scheduler_return"):
        if k in metrics:
            meta[k.split("/")[1]] = metrics[k]
    path = write_export(out, params, env=env, config=resolved, task=run.task, physics=run.physics, metadata=meta)
    print(f"export saved: {path}")
    print(f"success={metrics['eval/new_skill_success']:.4f} return={metrics['eval/new_skill_return']:.3f}")
