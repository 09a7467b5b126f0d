"""The tracked tree stays lean: a clone is the product, not the lab (issue 41).

Each check is a function of a plain list of tracked files (path and size, or path and text), so
every check is tested on a tiny made-up list as well as run on the real tree (``git ls-files``,
so it holds in a fresh clone too). One manifest steers them: ``models/training/in-progress.txt``
names the training runs still running (each may track its own checkpoints), one path per line,
``#`` starting a comment.
"""

from __future__ import annotations

import re
import subprocess
from fnmatch import fnmatch
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IN_PROGRESS = ROOT / "models" / "training" / "in-progress.txt"

MB = 1_000_000
CHECKPOINT_BUDGET = 30 * MB  # .pt files outside models/*.pt and the runs in progress
LARGEST_FILE = 10 * MB
TEXT_SUFFIXES = (".json", ".jsonl", ".txt", ".md", ".log", ".csv", ".toml", ".yaml", ".yml")
# an absolute path of the machine a file was made on (not part of a URL or a relative path)
MACHINE_PATH = re.compile(r"(?<![\w./~-])/(?:work|root|home|tmp|Users|mnt|scratch)/[\w.-]")
# what a run in progress may track: its resume point, its best model, a finished stage's mean (which
# stands for its snapshots), the snapshots a pending mean still needs, and small records
IN_PROGRESS_ALLOWED = ("*/latest.pt", "*/best.pt", "*/mean.pt", "*/snapshots/*.pt", "*.json", "*.jsonl", "*.log",
                       "*.txt", "*.md", "*.toml", "*.csv", "*.gz")


def read_manifest(path: Path) -> list[str]:
    """The paths a manifest lists, without comments and blank lines."""
    if not path.exists():
        return []
    lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
    return [line.rstrip("/") for line in lines if line]


def tracked_files() -> list[str]:
    """Tracked paths that exist in the work tree (a deletion not yet committed counts as done)."""
    def listed(*flags: str) -> list[str]:
        out = subprocess.run(["git", "ls-files", "-z", *flags], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout
        return [p for p in out.split("\0") if p]

    deleted = set(listed("--deleted"))
    return [p for p in listed() if p not in deleted]


def inside(path: str, folders: list[str]) -> bool:
    return any(path.startswith(folder + "/") for folder in folders)


def checkpoints_over_budget(sizes: dict[str, int], in_progress: list[str],
                            budget: int = CHECKPOINT_BUDGET) -> list[str]:
    """The stray checkpoints (largest first) when together they exceed ``budget``, else []."""
    shipped = re.compile(r"models/[^/]+\.pt")
    stray = [p for p in sizes if p.endswith(".pt") and not shipped.fullmatch(p)
             and not inside(p, in_progress)]
    if sum(sizes[p] for p in stray) <= budget:
        return []
    return sorted(stray, key=lambda p: -sizes[p])


def oversized(sizes: dict[str, int], limit: int = LARGEST_FILE) -> list[str]:
    """Files larger than ``limit`` bytes."""
    return sorted(p for p, size in sizes.items() if size > limit)


def with_machine_paths(texts: dict[str, str]) -> list[str]:
    """JSON and text files that hold an absolute path of a machine."""
    return sorted(p for p, text in texts.items() if p.endswith(TEXT_SUFFIXES) and MACHINE_PATH.search(text))


def disallowed_in_progress(tracked: list[str], in_progress: list[str]) -> list[str]:
    """Files a run in progress tracks beyond its checkpoints, snapshots and small records, and
    the models of its finished seeds (a ``model.pt`` beside the ``selection.json`` that chose it)."""
    finished = {p.rsplit("/", 1)[0] for p in tracked if p.endswith("/selection.json")}
    return sorted(p for p in tracked if inside(p, in_progress)
                  and not any(fnmatch(p, pattern) for pattern in IN_PROGRESS_ALLOWED)
                  and not (p.endswith("/model.pt") and p.rsplit("/", 1)[0] in finished))


def unshown_figures(tracked: list[str], pages: dict[str, str]) -> list[str]:
    """Figures under eval/ that no page names: `formic eval --out DIR --report` rebuilds them
    from the folder's episodes, so only those a page shows are worth their bytes."""
    return sorted(p for p in tracked if p.startswith("eval/") and p.endswith(".png")
                  and not any("/".join(p.split("/")[-2:]) in text for text in pages.values()))


# --- the real tree -------------------------------------------------------------------------------

def tree_sizes() -> dict[str, int]:
    return {p: (ROOT / p).stat().st_size for p in tracked_files()}


def test_stray_checkpoints_stay_within_budget():
    stray = checkpoints_over_budget(tree_sizes(), read_manifest(IN_PROGRESS))
    assert stray == [], f"tracked checkpoints over {CHECKPOINT_BUDGET // MB} MB, largest first: {stray[:20]}"


def test_no_tracked_file_is_over_10_mb():
    assert oversized(tree_sizes()) == []


def test_no_json_or_text_file_holds_a_machine_path():
    texts = {p: (ROOT / p).read_text(errors="replace") for p in tracked_files() if p.endswith(TEXT_SUFFIXES)}
    assert with_machine_paths(texts) == []


def test_an_evaluations_figures_are_tracked_only_where_a_page_shows_them():
    pages = {p: (ROOT / p).read_text() for p in tracked_files() if p.endswith(".md")}
    assert unshown_figures(tracked_files(), pages) == []


def test_runs_in_progress_track_only_checkpoints_and_records():
    assert disallowed_in_progress(tracked_files(), read_manifest(IN_PROGRESS)) == []


def test_the_manifests_name_the_run_in_progress():
    runs = read_manifest(IN_PROGRESS)
    assert runs and all(run.startswith("models/training/") and "/" not in run[len("models/training/"):]
                        for run in runs), runs  # whole run folders, one level under models/training
    assert (ROOT / "models/training/cpu-v3/latest.pt").exists()  # a resume test's fixture


# --- each check on a tiny made-up tree -----------------------------------------------------------

def test_read_manifest_drops_comments_blanks_and_trailing_slashes(tmp_path):
    manifest = tmp_path / "m.txt"
    manifest.write_text("# why\n\nmodels/training/run/  # a run\nb.pt\n")
    assert read_manifest(manifest) == ["models/training/run", "b.pt"]
    assert read_manifest(tmp_path / "absent.txt") == []


def test_checkpoints_over_budget_counts_only_stray_checkpoints():
    sizes = {"models/formic.pt": 50, "models/training/a/model.pt": 8, "models/training/a/x/latest.pt": 4,
             "models/training/live/latest.pt": 40, "models/training/old/mean.pt": 30, "eval/e.json": 99}
    assert checkpoints_over_budget(sizes, ["models/training/live"], 42) == []
    assert checkpoints_over_budget(sizes, ["models/training/live"], 41) == [
        "models/training/old/mean.pt", "models/training/a/model.pt", "models/training/a/x/latest.pt"]
    assert checkpoints_over_budget(sizes, [], 81) == [
        "models/training/live/latest.pt", "models/training/old/mean.pt", "models/training/a/model.pt",
        "models/training/a/x/latest.pt"]


def test_oversized_names_files_over_the_limit_only():
    sizes = {"a.jsonl": 11, "b.pt": 10, "c.json": 12}
    assert oversized(sizes, 10) == ["a.jsonl", "c.json"]
    assert oversized(sizes, 12) == []


def test_with_machine_paths_finds_absolute_paths_in_text_files_only():
    texts = {"run/config.json": '{"init": "/work/main/models/a.pt"}', "run/train.log": "from /root/x",
             "run/results.md": "Scenarios: models/training/run/validation", "src/a.py": "'/work/x'",
             "README.md": "see https://host/home/page and ~/work/x", "run/old.json": '"/tmp/x"'}
    assert with_machine_paths(texts) == ["run/config.json", "run/old.json", "run/train.log"]


def test_unshown_figures_are_those_no_page_names_by_folder_and_name():
    tracked = ["eval/a/seed3/food.png", "eval/a/seed2/food.png", "eval/b/curves.png", "docs/x.png", "eval/b/r.md"]
    pages = {"README.md": "![food](eval/a/seed3/food.png)", "docs/results.md": "see ../eval/b/"}
    assert unshown_figures(tracked, pages) == ["eval/a/seed2/food.png", "eval/b/curves.png"]


def test_disallowed_in_progress_keeps_a_run_to_checkpoints_and_records():
    tracked = ["models/training/v2/recipe.json", "models/training/v2/basics/latest.pt",
               "models/training/v2/crowd/snapshots/episode00008.pt", "models/training/v2/crowd/mean.pt",
               "models/training/v2/basics/tb/events.out.tfevents.1.vm.2.0", "models/training/v2/seed1.log",
               "models/training/v2/validation/a/curves.png", "models/training/done/crowd/mean.pt",
               "models/training/v2/seed1/model.pt", "models/training/v2/seed1/selection.json",
               "models/training/v2/seed2/model.pt"]  # seed 1 finished; seed 2's model not chosen yet
    assert disallowed_in_progress(tracked, ["models/training/v2"]) == [
        "models/training/v2/basics/tb/events.out.tfevents.1.vm.2.0", "models/training/v2/seed2/model.pt",
        "models/training/v2/validation/a/curves.png"]
