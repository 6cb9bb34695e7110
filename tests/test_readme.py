"""Every shell command of README.md runs as written, so the README cannot drift from the command
lines: the ```bash blocks are read in order and each command runs in one scratch directory, with
flags appended that shrink it (``SHRINK``: argparse takes the last value of a flag given twice).
A command that reads what an earlier one wrote (the quickstart's run directory, the skill trained
for --skill_dir) runs after it; independent chains of commands run two at a time. The install line
is not rerun; commands that need GPUs or several hosts are not run, but each of their flags must be
one their command's --help lists."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = os.path.join(ROOT, "README.md")
# Appended to every command of the module (a resumed run: RESUME): at most a few iterations,
# evaluations of a few episodes, one stage / seed / variant.
SHRINK = {
    "training.run": ["--num_timesteps", "1600", "--eval_episodes", "2"],
    "training.evaluate": ["--episodes", "2"],
    "training.train_skill": ["--bc_envs", "8", "--bc_steps", "20", "--bc_updates", "10", "--crr_steps", "0",
                             "--eval_episodes", "2"],
    "training.chain": ["--stages", "lift_green", "--lift_timesteps", "1600", "--eval_episodes", "2"],
    "training.experiments.paper": ["--methods", "skills", "--seeds", "0", "--budgets", "lift=1600,stack=1600",
                                   "--jobs", "1"],
    "training.plot": [],
}
RESUME = ["--num_timesteps", "3200"]  # training.run --resume: extends the quickstart's 1600
DEVICE_SECTION = "## One GPU, many GPUs, many hosts"


def readme_commands(text: str) -> list:
    """``(section heading, command)`` of each command of the ```bash blocks, in order: continued
    lines joined, comments and blank lines dropped."""
    out, section, block = [], "", None
    for line in text.splitlines():
        if block is None:
            if line.startswith("## "):
                section = line
            elif line.strip() == "```bash":
                block = []
            continue
        if line.strip() == "```":
            joined = "\n".join(block).replace("\\\n", " ")
            for cmd in joined.splitlines():
                cmd = re.sub(r"\s+#\s.*$", "", cmd).strip()
                if cmd and not cmd.startswith("#"):
                    out.append((section, cmd))
            block = None
        else:
            block.append(line)
    return out


def module_of(argv: list) -> str | None:
    """The ``python -m MODULE`` of a command's words (after any ``VAR=value`` or ``srun`` prefix)."""
    for i, word in enumerate(argv[:-2]):
        if word == "python" and argv[i + 1] == "-m":
            return argv[i + 2]
    return None


COMMANDS = readme_commands(open(README, encoding="utf-8").read())


def test_the_readme_has_commands_and_every_module_has_its_shrink():
    runnable = [c for s, c in COMMANDS if not c.startswith("pip ") and s != DEVICE_SECTION]
    assert len(runnable) >= 10, runnable
    for cmd in runnable:
        assert module_of(shlex.split(cmd)) in SHRINK, f"no SHRINK entry for {cmd!r}"


def _env():
    cache = os.environ.get("PARALLEL_SKILLS_TEST_CACHE",
                           os.path.join(os.path.expanduser("~"), ".cache", "parallel_skills_jax"))
    return dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
                JAX_COMPILATION_CACHE_DIR=cache, MPLBACKEND="Agg")


def _help(module: str) -> str:
    return subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT, env=_env(), capture_output=True,
                          text=True, check=True).stdout


def test_commands_that_need_gpus_or_hosts_use_flags_their_command_has():
    device = [c for s, c in COMMANDS if s == DEVICE_SECTION]
    assert device, f"README has no commands under {DEVICE_SECTION!r}"
    helps = {}
    for cmd in device:
        argv = shlex.split(cmd)
        module = module_of(argv)
        helps.setdefault(module, _help(module))
        unknown = [f for f in (w.split("=")[0] for w in argv if w.startswith("--"))
                   if not re.search(rf"(?<![\w-]){re.escape(f)}(?![\w-])", helps[module])]
        assert not unknown, f"{cmd!r}: {unknown} not in python -m {module} --help"


def outputs(argv: list) -> list:
    """The paths a command writes: its ``--out`` (and that file's directory for a file)."""
    out = [argv[i + 1] for i, w in enumerate(argv[:-1]) if w == "--out"]
    return out + [os.path.dirname(o) for o in out if os.path.splitext(o)[1] and os.path.dirname(o)]


def chains(commands: list) -> list:
    """The commands grouped so that one reading a path an earlier one writes (a word that is that
    path or below it) is in its group, each group in README order."""
    groups = []
    for cmd in commands:
        words = shlex.split(cmd)
        reads = lambda path: any(w == path or w.startswith(path + "/") or w.startswith(path + ":")  # noqa: E731
                                 for w in words)
        joined = [g for g in groups if any(reads(p) for c in g for p in outputs(shlex.split(c)))]
        merged = [c for g in joined for c in g] + [cmd]
        groups = [g for g in groups if g not in joined] + [sorted(merged, key=commands.index)]
    return groups


def run_chain(chain: list, workdir) -> list:
    """Run the commands of one chain in order: ``(command, extra flags, exit code, output, seconds)``."""
    done = []
    for cmd in chain:
        words = shlex.split(cmd)
        module = module_of(words)
        extra = RESUME if module == "training.run" and "--resume" in words else SHRINK[module]
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable] + words[words.index("python") + 1:] + extra, cwd=workdir, env=_env(),
                           capture_output=True, text=True, timeout=1500)
        done.append((cmd, extra, p.returncode, p.stdout + p.stderr, time.perf_counter() - t0))
        if p.returncode != 0:
            break
    return done


def test_chains_keep_readers_after_writers():
    cmds = ["python -m training.run --out runs/a", "python -m training.run --out my/x.npz",
            "python -m training.evaluate --policy runs/a:scheduler", "python -m training.run --skill_dir my",
            "python -m training.run --out runs/ab"]
    assert chains(cmds) == [[cmds[0], cmds[2]], [cmds[1], cmds[3]], [cmds[4]]]


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_every_readme_command_runs(tmp_path):
    """The README's commands (not the install line, not the devices section) in ``chains``, two
    chains at a time, each command shrunk by ``SHRINK``: every one exits 0, and an evaluation
    prints its success line last."""
    os.symlink(os.path.join(ROOT, "training"), tmp_path / "training")  # (its configs, as from the repository root)
    runnable = [c for s, c in COMMANDS if not c.startswith("pip ") and s != DEVICE_SECTION]
    groups = sorted(chains(runnable), key=len, reverse=True)
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = [r for chain in pool.map(lambda g: run_chain(g, tmp_path), groups) for r in chain]
    for cmd, extra, code, _, seconds in sorted(results, key=lambda r: runnable.index(r[0])):
        print(f"{seconds:6.1f} s  exit {code}  {cmd}  + {' '.join(extra)}")
    assert len(results) == len(runnable), "a command failed before the others of its chain ran"
    for cmd, extra, code, output, _ in results:
        assert code == 0, f"{cmd!r} + {extra}: exit {code}\n{output[-4000:]}"
        if module_of(shlex.split(cmd)) == "training.evaluate":
            assert output.strip().splitlines()[-1].startswith("success="), output[-500:]
