"""Every one-off analysis in analysis/ still starts: its command line parses and its imports
resolve (they import the project's modules, which move on without them)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
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


def test_collapse_signals_finds_the_first_held_departure():
    spec = importlib.util.spec_from_file_location("collapse_signals", ROOT / "analysis" / "collapse_signals.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    episodes = np.arange(4, 404, 4)
    values = np.where(np.arange(100) % 2 == 0, 1.0, -1.0)  # band 0 +/- 2 (k = 2, sd 1)
    values[60] = 50.0  # one spike: the 4-episode mean leaves the band for one point only
    values[80:] = 3.0  # a held rise above the band from episode 324
    assert module.first_departure(episodes, values, +1, 4, (0, 100), 2.0, 3) == 324
    assert module.first_departure(episodes, values, +1, 4, (0, 100), 2.0, 1) == 244
    assert module.first_departure(episodes, values, -1, 4, (0, 100), 2.0, 1) is None
