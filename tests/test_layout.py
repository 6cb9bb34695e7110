"""The repository's layout contracts: tasks/ stands alone, and docs/design.md has every section the
code points to."""

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
    for top in ("parallel_skills", "tasks", "training", "tests", "bench", "docs", "checkpoints"):
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
