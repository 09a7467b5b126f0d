"""Docs run: every fenced code block in README.md and docs/*.md, and every inline command, is
checked against the code, so that a reader who copies one gets what the docs promise.

A block's language tag decides its check (an untagged block fails: tag it):

- ``bash``/``sh``: split into commands (``\\`` continuations, comments, ``&``, ``;``, ``&&``,
  ``VAR=value`` and ``sudo`` prefixes, ``export``, ``cd``). A ``formic`` command is parsed by the
  real click group (``formic_cli.main.cli``: ``make_context`` down to the subcommand,
  ``resilient_parsing=False``), so an unknown option, a bad choice or range and a missing
  argument fail with the block's file and line; it is not run. Paths need not exist while
  parsing (an earlier command makes them, or the reader brings them). A script
  (``scripts/...``, ``python examples/...``) must exist and answer ``--help``;
  ``scripts/eval_readme.sh`` and ``scripts/eval_model.sh`` run with their ``FORMIC`` hook pointing
  at a recorder and every ``formic`` command they would run is parsed. ``python robot_agent.py`` is a program the reader
  saves from a marked block (:data:`SAVED_FROM_BLOCKS`): that block must be in the docs.
- ``python``: run as written in a subprocess (the venv's python, a fresh working directory, a
  timeout); every block is self-contained. A block right after
  ``<!-- docs-test: robot-snippet -->`` or ``<!-- docs-test: sim-client -->`` needs a running
  world and has an end-to-end test of its own: skipped here.
- ``json``: parses.
- ``text``: a program's output, equal to what the code prints (:data:`OUTPUTS`), or a file
  layout whose every listed path exists.
- inline code spans: ``formic ...`` names a command and options that exist (prose spans carry
  placeholders such as ``DIR`` or stop at an option's name, so values are not parsed); a script
  path exists; ``from ... import ...`` runs.

Executed for real, each in a temporary directory (:data:`EXECUTED`, all from the README's task
table): ``formic scenarios generate ...`` and ``formic bench world`` as written,
``formic sim ... --gif`` cut to 40 steps (its 512 take ~15 s), ``formic eval --out eval/readme
--report`` on a copy of ``eval/readme``; and every python block and span. Parsed only: the rest
(ROS runs and nodes, training, evaluation matrices, several machines: minutes to hours), and
``scripts/run.sh`` and ``scripts/test.sh`` behind ``--help``. ``test_coverage`` prints which block
got which check.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from importlib.util import find_spec
from pathlib import Path

import click
import pytest

from formic_cli.main import cli
from formic_view import DEFAULT_HOST, DEFAULT_PORT, address, announcement

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable  # the venv's (scripts/test.sh)
FORMIC = str(Path(sys.executable).with_name("formic"))  # its console script: the docs' `formic`
FORMIC_NAMES = {"formic", ".venv/bin/formic"}
PYTHON_NAMES = {"python", "python3", ".venv/bin/python"}
SHELL_TAGS = {"bash", "sh"}
SKIP_MARKERS = {"robot-snippet": "needs a running world: tests/test_ownership.py::test_the_readme_robot_program_drives_its_external_agent runs it as written",
                "sim-client": "needs a running world: tests/test_sim_control.py::test_the_docs_client_example_drives_a_paused_world runs it as written",
                "fake-robot": "needs a running world: tests/test_robot_runs.py::test_the_docs_fake_robot_decided_by_the_docs_agent_node runs it as written"}
SAVED_FROM_BLOCKS = {"robot_agent.py": "robot-snippet", "sim_client.py": "sim-client", "fake_robot.py": "fake-robot"}  # a program the reader saves -> its block's marker
OUTPUTS = {"live view:": lambda: announcement(address(DEFAULT_HOST, DEFAULT_PORT))}  # first words -> printer
SCRIPT_DIRS = ("scripts/", "examples/", "benchmarks/")
OPERATORS = {"&", "&&", ";", "||"}
ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")
FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})\s*([^\s`]*)")
MARKER = re.compile(r"^<!--\s*docs-test:\s*(\S+)\s*-->$")
SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.DOTALL)


@dataclass(frozen=True)
class Block:
    path: str  # relative to the repository
    line: int  # of the opening fence
    lang: str
    text: str
    marker: str | None  # NAME of a ``<!-- docs-test: NAME -->`` line right above

    @property
    def where(self) -> str:
        return f"{self.path}:{self.line}"


@dataclass(frozen=True)
class Span:
    path: str
    line: int
    text: str

    @property
    def where(self) -> str:
        return f"{self.path}:{self.line}"


def doc_files() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def read_markdown(path: Path) -> tuple[list[Block], list[Span]]:
    """The fenced blocks of one Markdown file, and the inline code spans outside them."""
    rel, lines = str(path.relative_to(ROOT)), path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    paragraphs: list[list[tuple[int, str]]] = [[]]
    i = 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            if lines[i].strip():
                paragraphs[-1].append((i + 1, lines[i]))
            else:
                paragraphs.append([])
            i += 1
            continue
        fence = opening.group(1)
        closing = re.compile(rf"^ {{0,3}}{fence[0]}{{{len(fence)},}}\s*$")
        end = next((j for j in range(i + 1, len(lines)) if closing.match(lines[j])), len(lines))
        above = MARKER.match(next((line.strip() for line in reversed(lines[:i]) if line.strip()), ""))
        blocks.append(Block(rel, i + 1, opening.group(2).lower(), "\n".join(lines[i + 1:end]),
                            above.group(1) if above else None))
        paragraphs.append([])
        i = end + 1
    spans = []
    for paragraph in filter(None, paragraphs):  # a span may wrap onto the next line
        text = "\n".join(line for _, line in paragraph)
        for match in SPAN.finditer(text):
            line = paragraph[text.count("\n", 0, match.start())][0]
            spans.append(Span(rel, line, " ".join(match.group(2).split())))
    return blocks, spans


DOCS = [read_markdown(path) for path in doc_files()]
BLOCKS = [block for blocks, _ in DOCS for block in blocks]
SPANS = [span for _, spans in DOCS for span in spans]


# ------------------------------------------------------------------------------- the CLI
def all_commands(group: click.Group = cli) -> Iterator[click.Command]:
    yield group
    for command in group.commands.values():
        yield from all_commands(command) if isinstance(command, click.Group) else (command,)


@contextmanager
def parse_only() -> Iterator[None]:
    """Parsing has no effects: paths that an earlier command makes (or the reader brings) need not
    exist yet, and the environment an eager option sets (``--hosts-network``) is restored."""
    paths = [p.type for c in all_commands() for p in c.params if isinstance(p.type, click.Path) and p.type.exists]
    environment = dict(os.environ)
    for path_type in paths:
        path_type.exists = False
    try:
        yield
    finally:
        for path_type in paths:
            path_type.exists = True
        os.environ.clear()
        os.environ.update(environment)


def parse_formic(args: list[str], where: str) -> None:
    """Resolve ``formic ARGS`` down to its subcommand as click does before running it."""
    command: click.Command = cli
    name, ctx, rest = "formic", None, list(args)
    try:
        with parse_only():
            while True:
                if isinstance(command, click.Group) and not rest:
                    raise click.UsageError(f"missing a command of `{name}`")  # click would print the help
                ctx = command.make_context(name, rest, parent=ctx, resilient_parsing=False)
                if not isinstance(command, click.Group):
                    return
                rest = [*ctx._protected_args, *ctx.args]  # what Group.invoke hands the subcommand
                name, command, rest = command.resolve_command(ctx, rest)
    except click.ClickException as exc:
        pytest.fail(f"{where}: `formic {shlex.join(args)}` does not parse: {exc.format_message()}", pytrace=False)


def reference_problem(args: list[str]) -> str | None:
    """What is wrong with a prose ``formic ARGS`` span: a command or an option it names that
    does not exist (None: nothing)."""
    command: click.Command = cli
    name = "formic"
    while isinstance(command, click.Group) and args and not args[0].startswith("-"):
        if args[0] not in command.commands:
            return f"`{name}` has no command {args[0]!r}"
        command, name, args = command.commands[args[0]], args[0], args[1:]
    known = {"-h", "--help", *(o for p in command.params for o in (*p.opts, *p.secondary_opts))}
    unknown = [t.split("=")[0] for t in args if re.match(r"^--?[A-Za-z]", t) and t.split("=")[0] not in known]
    return f"`{name}` has no option {', '.join(unknown)}" if unknown else None


# ------------------------------------------------------------------------------ running
def must_run(argv: list[str], what: str, **kwargs) -> None:
    """Run a command; a failure names what it was for and shows the end of its stderr."""
    done = subprocess.run(argv, capture_output=True, text=True, **kwargs)
    if done.returncode != 0:
        pytest.fail(f"{what} failed (status {done.returncode}):\n{done.stderr[-3000:]}", pytrace=False)


@cache
def answers_help(script: Path) -> None:
    """``SCRIPT --help`` exits 0 (once per session)."""
    argv = [PYTHON, str(script)] if script.suffix == ".py" else [str(script)]
    must_run([*argv, "--help"], f"`{script.relative_to(ROOT)} --help`", cwd=ROOT, timeout=120)


def run_python(code: str, where: str, cwd: Path) -> None:
    (cwd / "snippet.py").write_text(code + "\n")
    must_run([PYTHON, "snippet.py"], f"{where}: the python as written", cwd=cwd, timeout=120)


# ---------------------------------------------------------------------------- shell blocks
def shell_commands(block: Block) -> Iterator[tuple[int, list[str]]]:
    """(line, argv) of each simple command, continuations joined and comments dropped."""
    pending, start = "", block.line + 1
    for number, raw in enumerate(block.text.splitlines(), block.line + 1):
        if not pending:
            start = number
        if raw.endswith("\\"):
            pending += raw[:-1] + " "
            continue
        lexer = shlex.shlex(pending + raw, posix=True, punctuation_chars=True)
        lexer.whitespace_split = True
        pending, argv = "", []
        for token in [*lexer, ";"]:
            if token not in OPERATORS:
                argv.append(token)
            elif argv:
                yield start, argv
                argv = []


# scripts of formic commands taking hours: run with a ``FORMIC`` hook that records each command
EVALUATION_SCRIPTS = ("eval_readme.sh", "eval_model.sh")


def check_script(script: Path, where: str, tmp: Path, args: list[str] = ()) -> None:
    assert script.is_file(), f"{where}: no such file {script.relative_to(ROOT)}"
    if script.parent == ROOT / "scripts" and script.name in EVALUATION_SCRIPTS:
        check_evaluation_script(script, args, where, tmp)
        return
    assert script.suffix == ".py" or os.access(script, os.X_OK), f"{where}: {script.name} is not executable"
    answers_help(script)


def check_evaluation_script(script: Path, args: list[str], where: str, tmp: Path) -> None:
    """Hours of evaluation: run the script with ``FORMIC`` recording its commands, and parse each."""
    log, recorder = tmp / "formic_calls", tmp / "formic"
    log.unlink(missing_ok=True)
    recorder.write_text("#!/bin/sh\nprintf '%s\\0' \"$@\" >> \"$FORMIC_LOG\"\necho >> \"$FORMIC_LOG\"\n")
    recorder.chmod(0o755)
    env = {**os.environ, "FORMIC": str(recorder), "FORMIC_LOG": str(log)}
    env.pop("OUT_DIR", None)
    must_run([str(script), *args], f"{where}: {script.name} with a recording FORMIC", cwd=ROOT, env=env, timeout=60)
    calls = [line.split("\0")[:-1] for line in log.read_text().splitlines()]
    assert calls, f"{where}: {script.name} ran no formic command"
    for args in calls:
        parse_formic(args, f"{where} ({script.name})")


def check_shell_block(block: Block, tmp: Path) -> None:
    cwd = ROOT
    for line, argv in shell_commands(block):
        where = f"{block.path}:{line}"
        while argv[0] == "sudo" or ASSIGNMENT.match(argv[0]):
            argv = argv[1:]
        head, args = argv[0], argv[1:]
        if head == "export":
            assert args and all(ASSIGNMENT.match(a) for a in args), f"{where}: export needs NAME=value"
        elif head == "wait":  # waits for the block's background jobs: nothing to check
            assert not args, f"{where}: wait takes no job ids here"
        elif head == "cd":
            cwd = (cwd / args[0]).resolve()
            assert cwd.is_dir(), f"{where}: no such directory {args[0]}"
        elif head in FORMIC_NAMES:
            assert head == "formic" or (cwd / head).exists(), f"{where}: no {head}"
            parse_formic(args, where)
        elif head in PYTHON_NAMES and args[:1] == ["-m"]:
            assert find_spec(args[1]) is not None, f"{where}: no module {args[1]}"
        elif head in PYTHON_NAMES and args[0] in SAVED_FROM_BLOCKS:
            marker = SAVED_FROM_BLOCKS[args[0]]
            assert any(b.marker == marker for b in BLOCKS), (
                f"{where}: {args[0]} is the block marked {marker}, which the docs no longer have")
        elif head in PYTHON_NAMES:
            check_script(cwd / args[0], where, tmp)
        elif "/" in head:
            check_script(cwd / head, where, tmp, args)
        else:
            pytest.fail(f"{where}: no check for the command {head!r}: teach tests/test_docs.py one", pytrace=False)


# ---------------------------------------------------------------------------- other blocks
def check_text_block(block: Block) -> None:
    printer = next((printer for start, printer in OUTPUTS.items() if block.text.startswith(start)), None)
    if printer is not None:
        assert block.text == printer(), f"{block.where}: the program prints\n{printer()}\nnot\n{block.text}"
        return
    heads = [line.split()[0] for line in block.text.splitlines() if line.strip() and not line[0].isspace()]
    assert heads and all("/" in head for head in heads), (
        f"{block.where}: a text block is a program's output (add its printer to OUTPUTS) or a file layout")
    missing = [head for head in heads if not (ROOT / head).exists()]
    assert not missing, f"{block.where}: the layout lists paths that do not exist: {missing}"


def mode(block: Block) -> str:
    """What the test does with a block (test ids, coverage list)."""
    if block.marker in SKIP_MARKERS:
        return f"skipped ({block.marker})"
    if block.lang in SHELL_TAGS:
        return "parsed"
    return {"python": "executed", "json": "parsed", "text": "compared"}.get(block.lang, "unknown")


@pytest.mark.parametrize("block", BLOCKS, ids=[f"{b.where} {b.lang or '?'}" for b in BLOCKS])
def test_block(block: Block, tmp_path: Path) -> None:
    if block.marker in SKIP_MARKERS:
        pytest.skip(f"{block.where}: {SKIP_MARKERS[block.marker]}")
    if block.lang in SHELL_TAGS:
        check_shell_block(block, tmp_path)
    elif block.lang == "python":
        run_python(block.text, block.where, tmp_path)
    elif block.lang == "json":
        json.loads(block.text)
    elif block.lang == "text":
        check_text_block(block)
    else:
        pytest.fail(f"{block.where}: a block tagged {block.lang or '(nothing)'}: tag it bash, python, json "
                    "or text, or teach tests/test_docs.py the new kind", pytrace=False)


# ---------------------------------------------------------------------------- inline spans
def inline_kind(span: Span) -> tuple[str, list[str]]:
    """``formic``, ``script`` or ``python`` (with the span's words), or ``prose``."""
    try:
        words = shlex.split(span.text)
    except ValueError:  # a lone quote: prose
        return "prose", []
    while words and (words[0] == "sudo" or words[0] in PYTHON_NAMES):
        words = words[1:]
    if len(words) > 1 and words[0] in FORMIC_NAMES:
        return "formic", words[1:]
    if words and words[0].startswith(SCRIPT_DIRS):
        return "script", words
    if re.match(r"^(from \S+ )?import ", span.text):
        return "python", words
    return "prose", []


@pytest.mark.parametrize("path", [str(p.relative_to(ROOT)) for p in doc_files()])
def test_inline_commands(path: str, tmp_path: Path) -> None:
    problems = []
    for span in (s for s in SPANS if s.path == path):
        kind, words = inline_kind(span)
        if kind == "formic" and (problem := reference_problem(words)):
            problems.append(f"{span.where}: `{span.text}`: {problem}")
        elif kind == "script" and not (ROOT / words[0]).is_file():
            problems.append(f"{span.where}: no such file {words[0]}")
        elif kind == "python":
            run_python(span.text, span.where, tmp_path)
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------ executed commands
@dataclass(frozen=True)
class Run:
    command: str  # as the docs write it
    extra: tuple[str, ...] = ()  # appended to keep it cheap
    copy: str | None = None  # a repository folder the command reads, copied to the working directory
    makes: tuple[str, ...] = ()  # files it must write (removed from the copy first)


EXECUTED = (
    Run("formic scenarios generate --size 128 --agents 32 --count 50 --out scen/",
        makes=("scen/s128_n32_o0_infinite_w0_t1024_seed49.json",)),  # the 50th
    Run("formic sim --policy formic --agents 32 --size 128 --gif", extra=("--steps", "40"),
        makes=("out/sim/final.png", "out/sim/episode.gif")),
    Run("formic bench world"),
    Run("formic eval --out eval/readme --report", copy="eval/readme", makes=("eval/readme/results.md",)),
)


def documented_at(command: str) -> list[str]:
    """Where the docs write ``command``, as an inline span or a line of a shell block."""
    lines = [f"{b.path}:{n}" for b in BLOCKS if b.lang in SHELL_TAGS for n, argv in shell_commands(b)
             if shlex.join(argv) == command]
    return lines + [s.where for s in SPANS if s.text == command]


@pytest.mark.parametrize("run", EXECUTED, ids=[r.command for r in EXECUTED])
def test_executed(run: Run, tmp_path: Path) -> None:
    assert documented_at(run.command), f"`{run.command}` is no longer in the docs: update EXECUTED"
    if run.copy:
        shutil.copytree(ROOT / run.copy, tmp_path / run.copy)
    for made in run.makes:
        (tmp_path / made).unlink(missing_ok=True)
    must_run([FORMIC, *shlex.split(run.command)[1:], *run.extra], f"`{run.command}`", cwd=tmp_path, timeout=120)
    missing = [made for made in run.makes if not (tmp_path / made).is_file()]
    assert not missing, f"`{run.command}` did not write {missing}"


# ------------------------------------------------------------------------ the test itself
@pytest.mark.parametrize("command, error", [
    ("formic run --agnets 8", "No such option '--agnets'"),
    ("formic sim --timing exact", "'exact' is not one of"),
    ("formic sim --steps 0", "0 is not in the range"),
    ("formic scenarios generate --count 5", "Missing option '--out'"),
    ("formic bench", "missing a command of `bench`"),
    ("scripts/no_such_script.sh", "no such file"),
    ("frobnicate --now", "no check for the command"),
])
def test_a_broken_block_fails(command: str, error: str, tmp_path: Path) -> None:
    with pytest.raises((AssertionError, pytest.fail.Exception), match=error):
        check_shell_block(Block("README.md", 1, "bash", command, None), tmp_path)


def test_a_misspelled_inline_option_is_found() -> None:
    assert reference_problem(["bench", "ros", "--stpes", "600"]) == "`ros` has no option --stpes"
    assert reference_problem(["frobnicate"]) == "`formic` has no command 'frobnicate'"
    assert reference_problem(["replay", "DIR", "--verify"]) is None


# ------------------------------------------------------------------- the docs state the present
README_MAX_LINES = 300
# an internal work-log number ("issue 25", "sessions 11-17", "(session 12)"): no outside reader can
# look one up; only the changelog keeps dated entries
WORK_LOG = re.compile(r"\b(?:issue|session|PR)s?\s+#?\d+", re.IGNORECASE)
WORK_LOG_ALLOWED = {"docs/changelog.md"}


def work_log_citations(path: str, text: str) -> list[str]:
    """``path:line: match`` for each work-log citation in ``text`` (one may wrap a line)."""
    return [f"{path}:{text.count(chr(10), 0, m.start()) + 1}: {' '.join(m.group().split())!r}"
            for m in WORK_LOG.finditer(text)]


def test_no_work_log_citations_in_readme_or_docs() -> None:
    found = [hit for path in doc_files() if (rel := str(path.relative_to(ROOT))) not in WORK_LOG_ALLOWED
             for hit in work_log_citations(rel, path.read_text(encoding="utf-8"))]
    assert not found, "say the fact, not the work log's number:\n" + "\n".join(found)


def test_work_log_citations_are_found() -> None:
    text = "fixed (issue 25), the default of sessions\n11-17 and Issue #3; not an issue of 4 or 2 sessions"
    assert work_log_citations("x.md", text) == ["x.md:1: 'issue 25'", "x.md:1: 'sessions 11'", "x.md:2: 'Issue #3'"]


def test_readme_is_short() -> None:
    lines = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines: move details to docs/ (at most {README_MAX_LINES})"


def test_coverage(capsys: pytest.CaptureFixture) -> None:
    """Print what each block and inline span gets; every block has a check."""
    lines = [f"{b.where:24} {b.lang or '?':7} {mode(b)}" for b in BLOCKS]
    for run in EXECUTED:
        written = shlex.join([*shlex.split(run.command), *run.extra])
        lines.append(f"{', '.join(documented_at(run.command)) or '?':24} inline  executed: {written}")
    kinds = [(span, inline_kind(span)[0]) for span in SPANS]
    lines += [f"{span.where:24} inline  executed: {span.text}" for span, kind in kinds if kind == "python"]
    lines.append(f"{'':24} inline  names checked: {sum(kind == 'formic' for _, kind in kinds)} `formic ...` spans, "
                 f"{sum(kind == 'script' for _, kind in kinds)} script paths")
    with capsys.disabled():
        print("\ntests/test_docs.py: docs blocks and what they get\n  " + "\n  ".join(lines))
    assert "unknown" not in {mode(b) for b in BLOCKS}, "a block without a check (see test_block)"
