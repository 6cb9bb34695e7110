"""Every shell command of README.md runs as written, so the README cannot drift from the command
lines: the ```bash blocks are read in order and each command runs in one scratch directory (later
commands read what earlier ones wrote: the quickstart's run directory, the skill trained for
--skill_dir), with flags appended that shrink it (``SHRINK``: argparse takes the last value of a
flag given twice). The install line is not rerun; commands that need GPUs or several hosts are not
run, but each of their flags must be one their command's --help lists."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = os.path.join(ROOT, "README.md")
# Appended to every command of the module (a resumed run: RESUME): at most a few iterations,
# evaluations of a few episodes, one stage / seed / variant.
SHRINK = {
    "training.run": ["--num_timesteps", "1600"],
    "training.evaluate": ["--episodes", "2"],
    "training.train_skill": ["--bc_envs", "8", "--bc_steps", "20", "--bc_updates", "10", "--crr_steps", "0",
                             "--eval_episodes", "2"],
    "training.chain": ["--stages", "lift_green", "--lift_timesteps", "1600", "--eval_episodes", "2"],
    "training.experiments.paper": ["--methods", "skills", "--seeds", "0", "--budgets", "lift=1600,stack=1600",
                                   "--jobs", "1"],
    "training.plot": [],
}
RESUME = ["--num_timesteps", "3200"]  # training.run --resume: extends the quickstart's 1600
NOT_RUN = {"pip": "installs the package (not rerun)",
           "devices": "needs GPUs or several hosts"}
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


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A scratch directory standing for the repository root: ``training`` (its configs) linked in."""
    path = tmp_path_factory.mktemp("readme")
    os.symlink(os.path.join(ROOT, "training"), path / "training")
    return path


def _env():
    cache = os.environ.get("PARALLEL_SKILLS_TEST_CACHE",
                           os.path.join(os.path.expanduser("~"), ".cache", "parallel_skills_jax"))
    return dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
                JAX_COMPILATION_CACHE_DIR=cache, MPLBACKEND="Agg")


_HELP: dict = {}


def _help(module: str) -> str:
    if module not in _HELP:
        _HELP[module] = subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT, env=_env(),
                                       capture_output=True, text=True, check=True).stdout
    return _HELP[module]


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("section, cmd", COMMANDS, ids=[f"{i:02d}" for i in range(len(COMMANDS))])
def test_readme_command(section, cmd, workdir):
    argv = shlex.split(cmd)
    if argv[0] == "pip":
        pytest.skip(NOT_RUN["pip"])
    module = module_of(argv)
    assert module is not None, f"not a python -m command: {cmd!r}"
    if section == DEVICE_SECTION:
        flags = [w.split("=")[0] for w in argv if w.startswith("--")]
        unknown = [f for f in flags if not re.search(rf"(?<![\w-]){re.escape(f)}(?![\w-])", _help(module))]
        assert not unknown, f"{cmd!r}: {unknown} not in python -m {module} --help"
        pytest.skip(NOT_RUN["devices"])
    words = argv[argv.index("python"):]
    extra = RESUME if module == "training.run" and "--resume" in words else SHRINK[module]
    done = subprocess.run([sys.executable] + words[1:] + extra, cwd=workdir, env=_env(), capture_output=True,
                          text=True, timeout=1500)
    assert done.returncode == 0, f"{cmd!r} + {extra}: exit {done.returncode}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    if module == "training.evaluate":
        assert done.stdout.strip().splitlines()[-1].startswith("success="), done.stdout[-500:]
