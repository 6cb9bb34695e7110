"""The repository's layout contracts: tasks/ stands alone (it imports nothing of parallel_skills,
training or research), docs/design.md has every section the code points to, and every link and
docs/ path of README.md and docs/ exists."""

import glob
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_tasks_imports_nothing_of_the_algorithm():
    code = ("import sys, tasks; tasks.make('lift'); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('parallel_skills', 'training')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def _design_sections():
    with open(os.path.join(ROOT, "docs", "design.md")) as f:
        return {line[3:].strip() for line in f if line.startswith("## ")}


def test_every_design_reference_names_a_section_of_docs_design_md():
    sections = _design_sections()
    refs = []
    for top in ("parallel_skills", "tasks", "training", "research", "tests", "bench", "docs", "checkpoints"):
        for dirpath, _, files in os.walk(os.path.join(ROOT, top)):
            for name in files:
                if name.endswith((".py", ".md")):
                    with open(os.path.join(dirpath, name), encoding="utf-8") as f:
                        text = f.read()
                    if name != "test_layout.py":  # the old name of the document, which the repository never had
                        assert "DESIGN" + ".md" not in text and "DESIGN " + '"' not in text, name
                    refs += [(name, m) for m in re.findall(r'design\.md "([^"]+)"', text)]
    assert len(refs) >= 10  # the code does point to it
    missing = [(name, r) for name, r in refs if r not in sections]
    assert not missing, f"sections not in docs/design.md: {missing}"


def test_no_module_of_tasks_imports_the_algorithm_or_the_trainer():
    """tasks/ is the environments alone: no file of it imports parallel_skills or training (the
    import test above covers what tasks.make('lift') loads; this one every file, lazy imports too)."""
    pattern = re.compile(r"^\s*(from|import)\s+(parallel_skills|training|research)\b", re.M)
    offenders = []
    for dirpath, _, files in os.walk(os.path.join(ROOT, "tasks")):
        for name in files:
            if name.endswith(".py"):
                path = os.path.join(dirpath, name)
                with open(path, encoding="utf-8") as f:
                    offenders += [f"{os.path.relpath(path, ROOT)}: {m.group(0).strip()}" for m in pattern.finditer(f.read())]
    assert not offenders, offenders


def test_after_skill_starts_act_as_the_library_skill_does():
    """tasks' own forward pass of a library skill (``skill_starts.load_policy``, for the
    ``after:NAME:K`` start states) gives the mean action of ``parallel_skills.Skill.load``, exactly."""
    import jax
    import numpy as np

    from parallel_skills import Skill
    from tasks.manipulation import layout as L
    from tasks.manipulation import skill_starts

    spec = skill_starts.parse("after:stack_yellow_on_blue:10")
    act = jax.jit(jax.vmap(skill_starts.load_policy(spec, L.OBS_SIZE, L.ACTION_SIZE)))
    skill = Skill.load(skill_starts.library_file(spec.skill), obs_size=L.OBS_SIZE, action_size=L.ACTION_SIZE)
    obs = jax.random.normal(jax.random.PRNGKey(0), (64, L.OBS_SIZE))
    want = jax.jit(jax.vmap(lambda o: skill.apply(skill.params, o, jax.random.PRNGKey(0))))(obs)
    np.testing.assert_array_equal(np.asarray(act(obs)), np.clip(np.asarray(want), -1.0, 1.0))


def _markdown_files():
    yield os.path.join(ROOT, "README.md")
    for dirpath, _, files in os.walk(os.path.join(ROOT, "docs")):
        if os.path.relpath(dirpath, ROOT).startswith(os.path.join("docs", "results")):
            continue
        yield from (os.path.join(dirpath, f) for f in files if f.endswith(".md"))


def test_every_link_and_docs_path_of_the_documentation_exists():
    """README.md and docs/ (results tables aside): every relative Markdown link resolves from its
    file, and every docs/... path named in the text exists from the repository root."""
    link = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")
    named = re.compile(r"(?<![\w./])(docs/[\w./=\-]+\.(?:md|png|json|csv))")
    missing = []
    for path in _markdown_files():
        with open(path, encoding="utf-8") as f:
            text = f.read()
        for target in link.findall(text):
            if not re.match(r"^[a-z]+:", target) and not os.path.exists(os.path.join(os.path.dirname(path), target)):
                missing.append((os.path.relpath(path, ROOT), target))
        for target in named.findall(text):  # (a seed written S stands for every seed: _sS, seedS)
            pattern = re.sub(r"(_s|seed)S\.", r"\1[0-9]*.", target)
            if not glob.glob(os.path.join(ROOT, glob.escape(target) if pattern == target else pattern)):
                missing.append((os.path.relpath(path, ROOT), target))
    assert not missing, missing
