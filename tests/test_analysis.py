"""Every one-off analysis in analysis/ still starts: its command line parses and its imports
resolve (they import the project's modules, which move on without them)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ANALYSES = sorted((ROOT / "analysis").glob("*.py"))


def test_every_analysis_has_its_line_in_the_readme():
    readme = (ROOT / "analysis" / "README.md").read_text()
    assert ANALYSES and all(f"- `{path.name}`: " in readme for path in ANALYSES)


@pytest.mark.parametrize("script", ANALYSES, ids=lambda path: path.name)
def test_analysis_starts(script: Path):
    done = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120,
                          cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "Usage:" in done.stdout or "usage:" in done.stdout
