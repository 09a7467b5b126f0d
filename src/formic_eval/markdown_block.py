"""A generated block of a markdown file (the README's results, the paper's tables): the lines
between a begin and an end marker, rebuilt by the script the begin marker names, so that a
test can tell when the file no longer matches the evaluation folders it was built from."""

from __future__ import annotations

import sys
from pathlib import Path


def splice(text: str, begin: str, end: str, block: str) -> str:
    """``text`` with its block (``begin`` ... ``end``, markers included) replaced by ``block``."""
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        raise SystemExit(f"no generated block ({begin} ... {end}) to replace")
    return text[:start] + block + text[stop + len(end):]


def write_or_check(path: Path, begin: str, end: str, block: str, check: bool, command: str) -> int:
    """Replace the block in ``path``, or (``check``) return 1 with a hint when it is stale."""
    text = path.read_text()
    updated = splice(text, begin, end, block)
    if check:
        if updated != text:
            print(f"{path}'s block {begin} is stale: run {command} --write {path}", file=sys.stderr)
            return 1
        return 0
    path.write_text(updated)
    return 0


def add_block_options(parser, what: str) -> None:
    """``--write FILE`` and ``--check FILE`` for a script that builds ``what`` (one of them at most)."""
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--write", type=Path, metavar="FILE", help=f"replace the {what} block in this file")
    action.add_argument("--check", type=Path, metavar="FILE", help=f"exit 1 if this file's {what} block is stale")


def publish(lines: list[str], begin: str, end: str, args, command: str) -> int:
    """Print the block's lines, or (``args.write``/``args.check``) replace or check it between
    its markers in that file."""
    target = args.write or args.check
    if target is None:
        print("\n".join(lines))
        return 0
    return write_or_check(target, begin, end, "\n".join([begin, *lines, end]), check=args.check is not None,
                          command=command)
