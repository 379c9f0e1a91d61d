"""Every shell and Python example in README.md and docs/ runs, against the shipped samples,
so the docs cannot drift from the program (issue 26). A block that cannot run here (it
installs, needs a farm, or names placeholders) is marked just above its fence with
``<!-- not run: REASON -->``, and the reason is required."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
_FENCE = re.compile(r"(?:<!-- not run: (?P<why>[^>]*?) -->\n[ \t]*)?```(?P<lang>sh|python)\n(?P<body>.*?)```",
                    re.S)


def _examples():
    out = []
    for doc in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = doc.read_text(encoding="utf-8")
        for n, m in enumerate(_FENCE.finditer(text), 1):
            line = text.count("\n", 0, m.start("body"))
            out.append(pytest.param(m.group("lang"), m.group("body"), m.group("why"),
                                    id=f"{doc.relative_to(REPO)}:{line}"))
    return out


@pytest.mark.parametrize("lang, body, why", _examples())
def test_the_example_runs(lang, body, why, tmp_path):
    if why is not None:
        assert why.strip(), "a block marked 'not run' says why"
        pytest.skip(f"not run: {why}")
    shutil.copytree(REPO / "gbuffers", tmp_path / "gbuffers")
    bindir = Path(sys.executable).parent
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    cmd = ["bash", "-e", "-o", "pipefail", "-c", body] if lang == "sh" else [sys.executable, "-c", body]
    done = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
