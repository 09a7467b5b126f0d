"""Seal finished evaluations: each FOLDER's episode log becomes one deterministic ``episodes.jsonl.gz``.

    .venv/bin/python scripts/seal_episodes.py eval/readme eval/tables/reference

The sealed log is the compact form the repository keeps (``formic_eval.runner.EpisodeLog.seal``):
``formic eval --report`` and the table generators read it as they read the plain log, and a
resumed evaluation appends new episodes to a plain ``episodes.jsonl`` beside it, which the next
sealing folds in. Sealing the same episodes again gives the same bytes. With ``--drop-derived`` the folder also
loses what ``formic eval --report FOLDER`` rebuilds from the log: the per-episode exports
(``episodes.csv``, ``curves.csv``, ``results.json``) and the report's figures; ``results.md`` and
``results.csv`` stay, and so does a figure another script drew there (the README's).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from formic_eval.plots import REPORT_FIGURES
from formic_eval.runner import folder_log

# what `formic eval --report` writes from the episode log alone, beside the summaries kept
DERIVED = ("episodes.csv", "curves.csv", "results.json")


def seal(folder: Path, drop_derived: bool = False) -> str:
    """Seal one folder's log (and drop its derived exports); the line to print (episodes, bytes
    before and after)."""
    log = folder_log(folder)
    derived = [folder / name for name in DERIVED if drop_derived and (folder / name).exists()]
    derived += sorted(folder.glob(REPORT_FIGURES)) if drop_derived else []
    before = sum(path.stat().st_size for path in (log.path, log.sealed_path, *derived) if path.exists())
    sealed = log.seal()
    for path in derived:
        path.unlink()
    return f"{folder}: {len(log.load())} episodes, {before} -> {sealed.stat().st_size} bytes"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, metavar="FOLDER",
                        help="an evaluation folder (formic eval --out)")
    parser.add_argument("--drop-derived", action="store_true",
                        help=f"also delete {', '.join(DERIVED)} and the report's figures (formic eval --report "
                             "FOLDER rebuilds them)")
    args = parser.parse_args(argv)
    for folder in args.folders:
        try:
            print(seal(folder, args.drop_derived), flush=True)
        except ValueError as exc:
            raise SystemExit(f"seal_episodes: {exc}") from exc


if __name__ == "__main__":
    main()
