"""Seal finished evaluations: each FOLDER's episode log becomes one deterministic ``episodes.jsonl.gz``.

    .venv/bin/python scripts/seal_episodes.py eval/readme eval/tables/reference

The sealed log is the compact form the repository keeps (``formic_eval.runner.EpisodeLog.seal``):
``formic eval --report`` and the table generators read it as they read the plain log, and a
resumed evaluation appends new episodes to a plain ``episodes.jsonl`` beside it, which the next
sealing folds in. Sealing the same episodes again gives the same bytes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from formic_eval.runner import folder_log


def seal(folder: Path) -> str:
    """Seal one folder's log; the line to print (episodes, bytes before and after)."""
    log = folder_log(folder)
    before = sum(path.stat().st_size for path in (log.path, log.sealed_path) if path.exists())
    sealed = log.seal()
    return f"{folder}: {len(log.load())} episodes, {before} -> {sealed.stat().st_size} bytes"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, metavar="FOLDER",
                        help="an evaluation folder (formic eval --out)")
    args = parser.parse_args(argv)
    for folder in args.folders:
        try:
            print(seal(folder), flush=True)
        except ValueError as exc:
            raise SystemExit(f"seal_episodes: {exc}") from exc


if __name__ == "__main__":
    main()
