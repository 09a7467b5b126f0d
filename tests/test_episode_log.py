"""The sealed episode log (formic_eval.runner.EpisodeLog.seal, scripts/seal_episodes.py): a finished
evaluation's compact form, read by every report exactly as the plain log it came from."""

from __future__ import annotations

import gzip
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from formic_cli.main import cli
from formic_eval.matrix import PolicyOptions, Setting, generate_matrix
from formic_eval.runner import evaluate, folder_episodes, folder_log

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = [Setting(32, n, 0.0, "infinite", 30) for n in (3, 4)]


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished evaluation with a plain log (two algorithms, two team sizes, three scenarios each)."""
    out = tmp_path_factory.mktemp("evaluation") / "out"
    matrix = generate_matrix(SETTINGS, 3, seed=5, directory=out / "scenarios")
    evaluate(matrix, ["random", "csaf"], PolicyOptions(), out, workers=1, progress=False)
    return out


@pytest.fixture
def copy(finished, tmp_path) -> Path:
    out = tmp_path / "out"
    shutil.copytree(finished, out)
    return out


def _report(folder: Path) -> dict[str, bytes]:
    """What ``formic eval --report`` writes from a folder's episodes (the figures aside)."""
    result = CliRunner().invoke(cli, ["eval", "--report", "--out", str(folder)])
    assert result.exit_code == 0, result.output
    return {name: (folder / name).read_bytes()
            for name in ("results.md", "results.csv", "results.json", "episodes.csv", "curves.csv")}


def test_a_sealed_log_unpacks_to_its_plain_file_and_reports_the_same(copy, tmp_path):
    plain = (copy / "episodes.jsonl").read_bytes()
    records, report = folder_episodes(copy), _report(copy)
    assert len(records) == 12
    sealed = folder_log(copy).seal()
    assert sealed == copy / "episodes.jsonl.gz" and not (copy / "episodes.jsonl").exists()
    assert gzip.decompress(sealed.read_bytes()) == plain
    assert sealed.read_bytes()[4:8] == b"\0\0\0\0"  # gzip mtime 0
    assert folder_episodes(copy) == records
    assert _report(copy) == report


def test_sealing_is_deterministic(finished, tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    shutil.copytree(finished, first)
    shutil.copytree(finished, second)
    once = folder_log(first).seal().read_bytes()
    assert folder_log(second).seal().read_bytes() == once
    assert folder_log(first).seal().read_bytes() == once  # sealing a sealed folder changes nothing


def test_a_sealed_folder_with_a_plain_tail_reads_as_the_whole_plain_log(copy, tmp_path):
    lines = (copy / "episodes.jsonl").read_text().splitlines(keepends=True)
    records = folder_episodes(copy)
    whole = tmp_path / "whole"
    shutil.copytree(copy, whole)
    (copy / "episodes.jsonl").write_text("".join(lines[:10]))
    folder_log(copy).seal()
    (copy / "episodes.jsonl").write_text("".join(lines[10:]))
    assert folder_episodes(copy) == records
    assert folder_log(copy).seal().read_bytes() == folder_log(whole).seal().read_bytes()


def test_a_resumed_sealed_evaluation_runs_only_the_missing_episodes_into_a_plain_tail(copy):
    lines = (copy / "episodes.jsonl").read_text().splitlines(keepends=True)
    (copy / "episodes.jsonl").write_text("".join(lines[:-1]))
    folder_log(copy).seal()
    matrix = generate_matrix(SETTINGS, 3, seed=5, directory=copy / "scenarios")
    summary = evaluate(matrix, ["random", "csaf"], PolicyOptions(), copy, workers=1, progress=False)
    assert summary["episodes"] == {"total": 12, "done": 12, "computed": 1, "reused": 11}
    tail = (copy / "episodes.jsonl").read_text().splitlines()
    assert [json.loads(line)["key"] for line in tail] == [json.loads(lines[-1])["key"]]
    assert len(folder_episodes(copy)) == 12


def test_a_log_with_an_unreadable_line_is_not_sealed(copy):
    with open(copy / "episodes.jsonl", "a") as log:
        log.write("not json\n")
    before = (copy / "episodes.jsonl").read_bytes()
    with pytest.raises(ValueError, match="1 unreadable line"):
        folder_log(copy).seal()
    assert (copy / "episodes.jsonl").read_bytes() == before and not (copy / "episodes.jsonl.gz").exists()


def test_the_script_seals_each_folder_and_names_its_sizes(copy, tmp_path):
    size = (copy / "episodes.jsonl").stat().st_size
    empty = tmp_path / "empty"
    empty.mkdir()
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "seal_episodes.py"), str(copy)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"{copy}: 12 episodes, {size} -> {(copy / 'episodes.jsonl.gz').stat().st_size} bytes\n"
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "seal_episodes.py"), str(empty)],
                          capture_output=True, text=True)
    assert done.returncode == 1 and "no episodes to seal" in done.stderr
