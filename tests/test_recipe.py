"""``formic train --recipe``: stages, warm starts, means and the choice on validation, resumable.

The end-to-end runs use ``recipes/smoke.toml`` (three tiny stages, validation on 16x16 worlds),
the same code path as ``recipes/paper.toml``."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner, Result

from formic_agent.checkpoint import CheckpointError, load_network, read_checkpoint
from formic_cli.main import cli
from formic_eval.matrix import file_digest, layout_seed
from formic_eval.runner import folder_episodes
from formic_trainer.actor import filter_probability
from formic_trainer.config import load_train_config
from formic_trainer.learner import RESUMABLE
from formic_trainer.train import Trainer
from formic_trainer.recipes.definition import RecipeError, stage_config, trained, weights_file
from formic_trainer.recipes.files import load_recipe
from formic_trainer.recipes.run import cpu_seconds_left, run_recipe
from formic_trainer.recipes.validation import SELECTION_RULE
from formic_world.files import held_directory

ROOT = Path(__file__).resolve().parents[1]
SMOKE = load_recipe("smoke")


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run(run_dir: Path, stop_at: str | None = None) -> list[str]:
    """Run the smoke recipe; with ``stop_at``, a kill (Ctrl-C) at the first line holding it."""
    lines: list[str] = []

    def echo(line: str) -> None:
        lines.append(line)
        if stop_at is not None and stop_at in line:
            raise KeyboardInterrupt

    if stop_at is None:
        run_recipe(SMOKE, run_dir, seed=1, echo=echo)
    else:
        with pytest.raises(KeyboardInterrupt):
            run_recipe(SMOKE, run_dir, seed=1, echo=echo)
    return lines


def check_model_card(run_dir: Path, selection: dict, tmp_path: Path) -> None:
    """scripts/model_card.py on a finished run: the command that rebuilds it, one row per stage
    with what it changes, the candidates' validation food with the choice; a shipped copy that is
    not the run's model is refused; --write fills a card's block and --check then passes."""
    import subprocess
    import sys

    def card(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(ROOT / "scripts" / "model_card.py"), str(run_dir), *args],
                              capture_output=True, text=True, timeout=60)

    done = card()
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert f"**Built by** `formic train --recipe smoke --seed 1 --run-dir {run_dir}` (`recipes/smoke.toml`): 12 " \
        "training episodes" in done.stdout
    rows = [line for line in lines if line.startswith(("| first |", "| middle |", "| last |"))]
    assert [row.split(" | ")[1] for row in rows] == ["4 of 4", "4 of 4, mean of episodes 2-4 every 2",
                                                     "4 of 4, mean of episodes 2-4 every 2"]
    assert rows[1].split(" | ")[3] == "`learning_agents=1`" and "`valid_coef=0.0`" in rows[2].split(" | ")[3]
    chosen = next(line for line in lines if "(chosen)" in line)
    assert chosen.startswith(f"| **{selection['chosen']}** (chosen) | ")
    assert chosen.endswith(f" | {selection['candidates'][selection['chosen']]['food_mean']:.1f} |")
    other = tmp_path / "other.pt"
    other.write_bytes(b"not the model")
    refused = card("--model", str(other))
    assert refused.returncode == 1 and f"{other} is not {run_dir / 'model.pt'}" in refused.stderr
    page = tmp_path / "card.md"
    page.write_text(f"# A card\n\n<!-- card:begin (scripts/model_card.py {run_dir}) -->\n"
                    f"<!-- card:end {run_dir} -->\n\nBelow.\n")
    assert card("--check", str(page)).returncode == 1
    assert card("--write", str(page)).returncode == 0 and card("--check", str(page)).returncode == 0
    assert page.read_text().endswith(f"<!-- card:end {run_dir} -->\n\nBelow.\n")
    assert done.stdout.strip() in page.read_text()


def check_stage_validation(run_dir: Path, selection: dict) -> None:
    """scripts/stage_validation.py on a finished run: the end of every stage on the run's
    validation scenarios, the candidates' episodes reused (the same food as the choice read),
    the first stage's end (it has no mean: its latest weights) played into its own folder."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "stage_validation.py"), str(run_dir)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    header, *rows = done.stdout.splitlines()
    assert header.split() == ["stage", "end", "episodes", "food", "2", "3"]
    assert [row.split()[0] for row in rows] == ["first.latest", "middle.mean", "last.mean"]
    for row in rows[1:]:
        name, episodes, food = row.split()[:3]
        assert (int(episodes), float(food)) == (2, round(selection["candidates"][name]["food_mean"], 1))
    records = folder_episodes(run_dir / "validation" / "first.latest")
    assert sorted(r["agents"] for r in records) == [2, 3]
    assert {r["model"] for r in records} == {file_digest(run_dir / "first" / "latest.pt")}
    only = subprocess.run([sys.executable, str(ROOT / "scripts" / "stage_validation.py"), str(run_dir),
                           "--stages", "nothing"], capture_output=True, text=True, timeout=120)
    assert only.returncode == 1 and "no started stage among nothing" in only.stderr


def test_a_recipe_runs_every_stage_then_chooses_on_validation_and_resumes_after_a_kill(tmp_path):
    whole = tmp_path / "whole"
    lines = run(whole)
    assert "stage 2/3 middle: 4 episodes from first (a fresh optimiser) | recipe 4/12 episodes" in "\n".join(lines)
    assert lines[-1].startswith("recipe 12/12 episodes, ")
    # warm starts and seeds as the recipe says: `last` starts from `middle`'s mean
    last = load_train_config(whole / "last" / "config.json")
    assert last.init_weights == str(whole / "middle" / "mean.pt") and last.seed == 1003 and last.valid_coef == 0
    assert load_train_config(whole / "middle" / "config.json").init_weights == str(whole / "first" / "latest.pt")
    # a finished stage's checkpoint keeps no optimiser state (no later stage resumes it) and cannot be resumed
    for stage in ("first", "middle", "last"):
        assert "optimizer" not in read_checkpoint(whole / stage / "latest.pt")
    with pytest.raises(CheckpointError, match="holds no optimiser state .* start a new --run-dir from its weights"):
        Trainer(load_train_config(whole / "first" / "config.json"), whole / "first")
    # the mean names the snapshots of episodes 2 and 4
    sources = read_checkpoint(whole / "middle" / "mean.pt")["averaged_from"]
    assert [s.split()[0] for s in sources] == ["episode00002.pt", "episode00004.pt"]
    # the choice: validation episodes stored per candidate, on the seed-99 scenarios
    selection = json.loads((whole / "selection.json").read_text())
    scores = {name: selection["candidates"][name]["food_mean"] for name in SMOKE.candidates}
    assert selection["rule"] == SELECTION_RULE
    assert selection["chosen"] == max(SMOKE.candidates, key=scores.get)
    assert digest(whole / "model.pt") == digest(weights_file(whole, selection["chosen"]))
    first_seed = layout_seed(99, 16, 0.0, "infinite")
    for name in [*SMOKE.candidates, selection["chosen"] + "-channel-empty"]:
        records = folder_episodes(whole / "validation" / name)
        assert sorted((r["agents"], r["seed"]) for r in records) == [(2, first_seed), (3, first_seed)]
    check_model_card(whole, selection, tmp_path)
    check_stage_validation(whole, selection)

    # killed in the second stage, after its first episode set (its checkpoint is written)
    parts = tmp_path / "parts"
    run(parts, stop_at="| recipe 6/12 episodes")
    assert read_checkpoint(parts / "middle" / "latest.pt")["progress"]["episode"] == 2
    assert not (parts / "middle" / "snapshots" / "episode00002.pt").exists()
    status = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "1", "--run-dir", str(parts), "--status"])
    assert status.exit_code == 0, status.output
    lines = status.output.splitlines()
    assert lines[0].startswith("first: complete, 4 of 4 episodes, ") and lines[0].endswith(" CPU-h")
    assert lines[1].startswith("middle: in progress, 2 of 4 episodes, ")
    assert lines[2:4] == ["last: not started (4 episodes)", "validation: not started"]
    assert re.fullmatch(r"\d+\.\d\d of 0\.0 CPU-h spent", lines[4]), lines[4]  # smoke plans no costs: none left
    finished = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "1", "--run-dir", str(whole),
                                        "--status"]).output.splitlines()
    played = sorted([*SMOKE.candidates, selection["chosen"] + "-channel-empty", "first.latest"])  # (stage_validation)
    assert finished[3] == "validation: " + ", ".join(f"{name} 2 of 2 episodes" for name in played)
    assert finished[4].startswith(f"finished: model.pt = {selection['chosen']} (validation food "
                                  f"{selection['candidates'][selection['chosen']]['food_mean']:.1f}); ")
    first = digest(parts / "first" / "latest.pt")
    lines = run(parts)
    assert lines[0] == "stage 1/3 first: complete (4 episodes), skipped"
    assert "resuming at episode 2" in lines[1] and digest(parts / "first" / "latest.pt") == first
    # the resumed run ends where the uninterrupted one did
    for key, value in load_network(whole / "model.pt")[0].state_dict().items():
        assert torch.equal(value, load_network(parts / "model.pt")[0].state_dict()[key]), key

    # once more, through the command: a finished run is finished, with or without its stages' checkpoints
    def again(run_dir: Path = parts) -> Result:
        return CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "1", "--run-dir", str(run_dir)])

    stamps = {p: p.stat().st_mtime_ns for p in parts.glob("*/*.pt")}
    every_stamp = {p: p.stat().st_mtime_ns for p in parts.glob("**/*.pt")}
    result = again()
    assert result.exit_code == 0, result.output
    assert result.output == f"model: {parts / 'model.pt'} = {selection['chosen']}, chosen on validation " \
        f"({parts / 'selection.json'}): the run is finished\n"
    assert {p: p.stat().st_mtime_ns for p in parts.glob("**/*.pt")} == every_stamp
    lean = tmp_path / "lean"  # what the repository keeps of a finished run (scripts/lean_run.py)
    shutil.copytree(parts, lean)
    (lean / "validation" / "middle.mean" / "food_vs_team_s16_t128.png").write_bytes(b"png")  # the report's
    lean_run = [sys.executable, str(ROOT / "scripts" / "lean_run.py")]
    with held_directory(lean):  # a process still holds it (validating): refused, nothing removed
        held = subprocess.run([*lean_run, str(lean)], capture_output=True, text=True, timeout=60)
    assert held.returncode == 1 and "is in use by another process" in held.stderr, held.stderr
    assert (lean / "middle" / "mean.pt").exists()
    unfinished = subprocess.run([*lean_run, str(tmp_path / "whole" / "first")], capture_output=True, text=True,
                                timeout=60)
    assert unfinished.returncode == 1 and "has made no choice yet" in unfinished.stderr
    done = subprocess.run([*lean_run, str(lean)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    kept = sorted(p.relative_to(lean).as_posix() for p in lean.rglob("*") if p.is_file() and p.name != ".lock")
    validations = sorted(p.name for p in (lean / "validation").iterdir())
    assert kept == sorted(["model.pt", "recipe.json", "selection.json",
                           *(f"{stage}/{name}" for stage in ("first", "middle", "last")
                             for name in ("config.json", "progress.json")),
                           *(f"validation/{name}/{file}" for name in validations
                             for file in ("episodes.jsonl.gz", "results.csv", "results.md"))]), kept
    assert validations == sorted([*SMOKE.candidates, selection["chosen"] + "-channel-empty"])
    result = again(lean)
    assert result.exit_code == 0 and result.output.endswith("the run is finished\n"), result.output
    assert sorted(p.name for p in lean.glob("**/*.pt")) == ["model.pt"]
    (lean / "model.pt").write_bytes((parts / "first" / "latest.pt").read_bytes())
    result = again(lean)
    assert result.exit_code == 1 and f"{lean / 'model.pt'} is not the {selection['chosen']} that " \
        f"{lean / 'selection.json'} chose: restore it, or remove selection.json" in result.output, result.output
    (lean / "selection.json").write_text('{"chosen": "last.mean"')
    result = again(lean)
    assert result.exit_code == 1 and f"{lean / 'selection.json'} is not a readable choice (JSONDecodeError: " \
        in result.output and "remove it to validate and choose again" in result.output, result.output
    # without its selection, the stages are skipped and the validation episodes reused: the same model
    (parts / "selection.json").unlink()
    result = again()
    assert result.exit_code == 0, result.output
    assert result.output.count("complete (4 episodes), skipped") == 3 and " ep " not in result.output
    assert {p: p.stat().st_mtime_ns for p in parts.glob("*/*.pt")} == stamps
    assert json.loads((parts / "selection.json").read_text())["chosen"] == selection["chosen"]
    # a finished stage's mean stands for its snapshots (what a run in progress commits); without both, one line
    for snapshot in (parts / "middle" / "snapshots").glob("*.pt"):
        snapshot.unlink()
    (parts / "selection.json").unlink()
    result = again()
    assert result.exit_code == 0 and " ep " not in result.output and "skipped" in result.output, result.output
    assert {p: p.stat().st_mtime_ns for p in parts.glob("*/*.pt")} == stamps
    (parts / "middle" / "mean.pt").unlink()
    (parts / "selection.json").unlink()
    result = again()
    # (the stage's last snapshot is taken again from its latest.pt; the first is gone)
    assert result.exit_code == 1 and "middle: the mean needs episode00002.pt, which this run did not keep" \
        in result.output, result.output
    # another seed is another run
    result = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "2", "--run-dir", str(parts)])
    assert result.exit_code == 1 and "another recipe, switch, scale or seed" in result.output


SMOKE_TEXT = (ROOT / "recipes" / "smoke.toml").read_text()


def test_sigterm_stops_a_recipe_after_its_episode_set_with_the_checkpoint_saved(tmp_path):
    """`kill` on `formic train --recipe` is Ctrl-C: the stage's set in progress ends and is saved
    (here its only checkpoint: the first stage is long and checkpoints never on its own), the
    command exits 130 with the line that resumes it, and the run stands at that episode."""
    import signal

    recipe, run_dir = tmp_path / "long.toml", tmp_path / "run"
    recipe.write_text(SMOKE_TEXT.replace('episodes = 4\nstart = "scratch"', 'episodes = 400\nstart = "scratch"', 1)
                      .replace("checkpoint_every = 1\n", "checkpoint_every = 1000\n", 1))
    command = [sys.executable, "-m", "formic_cli.main", "train", "--recipe", str(recipe), "--seed", "1",
               "--run-dir", str(run_dir)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        for line in process.stdout:
            lines.append(line.rstrip("\n"))
            if line.startswith("first: ep "):
                process.send_signal(signal.SIGTERM)
                break
        lines += process.communicate(timeout=120)[0].splitlines()
    finally:
        process.kill()
        process.wait(timeout=30)
    assert process.returncode == 130, "\n".join(lines[-20:])
    assert lines[-1] == "interrupted: rerun the same command to resume" and "Traceback" not in "\n".join(lines)
    assert any(line.startswith("stop requested: the episode set in progress ends") for line in lines)
    episode = read_checkpoint(run_dir / "first" / "latest.pt")["progress"]["episode"]
    assert 2 <= episode < 400
    assert lines[-2].startswith(f"first: stopped at episode {episode}, its checkpoint saved | recipe {episode}/408 ")
    status = CliRunner().invoke(cli, [*command[3:], "--status"])
    assert status.output.splitlines()[0].startswith(f"first: in progress, {episode} of 400 episodes, ")


@pytest.mark.parametrize("old, new, message", [
    ("[[stage]]", "[[stage]", "not valid TOML"),
    ("valid_coef = 0.0", "valid_coeff = 0.0", "stage 'last'.set.valid_coeff is not a training setting"),
    ("valid_coef = 0.0", 'valid_coef = "none"', "stage 'last'.set.valid_coef must be float"),
    ("valid_coef = 0.0", "seed = 3", "stage 'last'.set.seed: given by --seed"),
    ("valid_coef = 0.0", 'training_filter = "strict"', "training_filter must be one of"),
    ('start = "middle.mean"', 'start = "first.mean"', "stage 'last': start 'first.mean' is not"),
    ('start = "first"', 'start = "last"', "stage 'middle': start 'last' is not"),
    ("episodes = 4\nstart = \"first\"", "episodes = 5\nstart = \"first\"", "multiples of its 2 worlds"),
    ("world_sizes = [[16, 16], [16, 20]]", "world_sizes = [[16, 16], [16]]", "world_sizes[1] must be a list of 2"),
    ('candidates = ["middle.mean", "last.mean"]', 'candidates = ["middle.mean", "nothing"]', "candidates 'nothing'"),
    ("scenarios = 1", "scenarios = 0", "validation.scenarios must be a whole number >= 1"),
    ('start = "middle.mean"', 'start = "middle.best"', "stage 'last': start 'middle.best': stage 'middle' keeps no "
                                                       "best.pt, its fall guard is off"),
    ('candidates = ["middle.mean", "last.mean"]', 'candidates = ["first.best", "last.mean"]',
     "candidates 'first.best': stage 'first' keeps no best.pt"),
    ('start = "scratch"', 'start = "scratch"\nscaled = "no"', "stage 'first'.scaled must be true or false"),
    ('start = "scratch"', 'start = "scratch"\ncost = 0', "stage 'first'.cost must be a number > 0 (CPU-seconds per "
                                                         "episode), not 0"),
    ("steps = 128", 'steps = 128\ncost = "6"', "validation.cost must be a number > 0 (CPU-seconds per episode), "
                                               "not '6'"),
])
def test_a_malformed_recipe_is_one_line_of_error_before_anything_runs(tmp_path, old, new, message):
    assert old in SMOKE_TEXT
    recipe = tmp_path / "bad.toml"
    recipe.write_text(SMOKE_TEXT.replace(old, new, 1))
    result = CliRunner().invoke(cli, ["train", "--recipe", str(recipe), "--seed", "1",
                                      "--run-dir", str(tmp_path / "run")])
    assert result.exit_code == 1
    assert result.output.startswith(f"Error: {recipe}: ") and result.output.count("\n") == 1, result.output
    assert message in result.output
    assert not (tmp_path / "run").exists()


def test_single_run_options_do_not_mix_with_a_recipe(tmp_path):
    for args in (["--recipe", "smoke", "--seed", "1", "--set", "lr=0.1"], ["--seed", "1"]):
        result = CliRunner().invoke(cli, ["train", *args, "--run-dir", str(tmp_path / "run")])
        assert result.exit_code == 2 and "--recipe" in result.output
    assert not (tmp_path / "run").exists()


def test_the_paper_recipe_validates_on_seeds_no_test_set_uses():
    """The stored test scenarios (eval/), `formic eval`'s default seed 0 and the README's 7 (any
    size, obstacle density and capacity, 50 scenarios each) and `formic scenarios generate`'s
    default seeds 0-49 never meet the validation scenarios."""
    v = load_recipe("paper").validation
    first = layout_seed(v.seed, v.size, 0.0, "infinite")
    validation = set(range(first, first + v.scenarios))
    stored = {int(re.search(r"_seed(\d+)\.json$", p.name)[1]) for p in ROOT.glob("eval/**/scenarios/*.json")}
    generated = {layout_seed(seed, size, obstacles, capacity) + k for seed in (0, 7) for size in (32, 64, 128)
                 for obstacles in (0.0, 0.05) for capacity in ("infinite", "finite") for k in range(50)}
    assert stored and stored <= generated
    assert not validation & (generated | set(range(50)))


@pytest.mark.parametrize("stage, lineage", [("nonlearning", "paper-feedback-nonlearning"),
                                            ("novalid", "paper-novalid"), ("novalid128", "paper-novalid128")])
def test_the_paper_recipes_last_stages_train_as_the_lineage_did(stage, lineage):
    """Stages 4-6 of models/formic_paper.md, setting for setting (the highway schedule, unused
    without the curriculum, is inherited from the recipe's reference stage)."""
    recipe = load_recipe("paper")
    index = [s.name for s in recipe.stages].index(stage)
    ours = stage_config(recipe, index, Path("run"), seed=1).to_dict()
    theirs = load_train_config(ROOT / "models" / "training" / lineage / "config.json").to_dict()
    differ = {key for key in ours if json.dumps(ours[key]) != json.dumps(theirs[key])}
    assert differ == {"seed", "init_weights", "total_episodes", "curriculum_start", "curriculum_end"}
    assert ours["curriculum"] is False


def test_a_switch_holds_in_every_stage_over_the_stages_own_settings():
    plain, switched = load_recipe("smoke"), load_recipe("smoke", "all-learn")
    assert plain.switches == switched.switches == ("blind", "all-learn")
    assert [s.settings.get("learning_agents") for s in plain.stages] == [None, 1, 1]
    assert [s.settings["learning_agents"] for s in switched.stages] == [-1, -1, -1]
    assert all(s.settings.items() - {("learning_agents", -1)} <= p.settings.items()
               for s, p in zip(switched.stages, plain.stages))
    assert switched.identity != plain.identity and switched.switch == "all-learn"
    result = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--switch", "sideways", "--seed", "1",
                                      "--run-dir", "unused"])
    assert result.exit_code == 1 and "no switch 'sideways' (switches: blind, all-learn)" in result.output


@pytest.mark.parametrize("old, new, message", [
    ('set = { pheromones = false }', 'set = { pheromone = false }', "switch 'blind'.set.pheromone is not a training"),
    ('about = "every agent learns"\n', '', "switch 'all-learn': missing about"),
])
def test_a_malformed_switch_is_an_error_even_unused(tmp_path, old, new, message):
    recipe = tmp_path / "bad.toml"
    recipe.write_text(SMOKE_TEXT.replace(old, new, 1))
    result = CliRunner().invoke(cli, ["train", "--recipe", str(recipe), "--seed", "1", "--run-dir", str(tmp_path / "r")])
    assert result.exit_code == 1 and message in result.output, result.output


def test_a_run_resumes_across_comment_edits_but_not_across_switches(tmp_path):
    """The claim holds what the run trains (its identity), so editing comments, the budget or
    other switches keeps a run resumable; another switch is another run. Claims written before
    identities existed (the recipe's text only) still resume."""
    from formic_trainer.recipes.run import RecipeRun

    edited = tmp_path / "edited.toml"
    edited.write_text("# a new comment\n" + SMOKE_TEXT.replace("budget_cpu_hours = 0.01", "budget_cpu_hours = 0.02"))
    RecipeRun(load_recipe("smoke"), tmp_path / "run", 1, print)
    RecipeRun(load_recipe(str(edited)), tmp_path / "run", 1, print)  # accepted
    with pytest.raises(Exception, match="another recipe, switch, scale or seed"):
        RecipeRun(load_recipe("smoke", "blind"), tmp_path / "run", 1, print)
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "recipe.json").write_text(json.dumps({"recipe": str(ROOT / "recipes" / "smoke.toml"), "seed": 1,
                                                    "text": SMOKE_TEXT}))
    RecipeRun(load_recipe(str(edited)), legacy, 1, print)
    with pytest.raises(Exception, match="another recipe, switch, scale or seed"):
        RecipeRun(load_recipe("smoke", "all-learn"), legacy, 1, print)


def test_a_run_resumes_on_another_thread_count_and_validates_in_as_many_processes(tmp_path):
    """--threads is how fast, not what is trained: a run killed on the recipe's one thread
    resumes on two (its claim unchanged), the resumed stage's configuration says so, and the
    validation runs in two processes."""
    parts = tmp_path / "parts"
    run(parts, stop_at="| recipe 6/12 episodes")
    claim = (parts / "recipe.json").read_text()
    assert json.loads(claim)["recipe"] == "recipes/smoke.toml"  # no machine path in a committed claim
    result = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "1", "--run-dir", str(parts),
                                      "--threads", "2"])
    assert result.exit_code == 0, result.output
    assert "resuming at episode 2, 2 torch thread(s)" in result.output
    assert (parts / "recipe.json").read_text() == claim
    assert load_train_config(parts / "middle" / "config.json").threads == 2
    assert load_train_config(parts / "first" / "config.json").threads == 1  # done before: untouched
    records = folder_episodes(parts / "validation" / "last.mean")
    assert {r["workers"] for r in records} == {2}
    bad = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "1", "--run-dir", str(parts),
                                   "--threads", "0"])
    assert bad.exit_code == 2 and "--threads" in bad.output


def test_a_recipe_trained_without_pheromones_is_validated_without_them(tmp_path):
    lines: list[str] = []
    run_recipe(load_recipe("smoke", "blind"), tmp_path / "blind", seed=1, echo=lines.append)
    selection = json.loads((tmp_path / "blind" / "selection.json").read_text())
    validated = [line for line in lines if line.startswith("validation: ")]
    assert len(validated) == 2 and all("(pheromone channel empty)" in line for line in validated)
    assert selection["channel_empty"]["less_by_team"] == {"2": 0.0, "3": 0.0}


def test_a_scaled_recipe_keeps_every_stage_and_schedule_in_proportion():
    """`--scale F` (rows of a table at one smaller budget): every stage's episodes and mean
    windows times F in whole episode sets, and its (start, end) schedules with them; a schedule
    that ends after its start still does (the crowd stage's filter, off after episode 1). The
    basics stage (`scaled = false`) stays whole; the budget shrinks with the episodes kept."""
    full, half = load_recipe("paper"), load_recipe("paper", scale=0.5)
    assert [s.name for s in half.stages] == [s.name for s in full.stages] and half.identity != full.identity
    assert [s.episodes for s in half.stages] == [300, 300, 164, 104, 248, 168]
    assert [s.average for s in half.stages] == [None, None, None, (48, 8), (192, 8), (120, 8)]
    assert half.stages[0] == full.stages[0]
    reference, crowd = half.stages[1].settings, half.stages[2].settings
    assert (reference["filter_anneal_start"], reference["filter_anneal_end"]) == (0, 300)
    assert (crowd["filter_anneal_start"], crowd["filter_anneal_end"]) == (0, 1)
    basics = stage_config(half, 0, Path("run"), seed=1)
    assert (basics.filter_anneal_start, basics.filter_anneal_end, basics.curriculum_start, basics.curriculum_end) == \
        (40, 300, 60, 300)  # the cpu preset's, as in the full recipe
    assert half.budget_cpu_hours == pytest.approx(full.budget_cpu_hours * 1284 / 2268)
    for bad in ("0", "1.5"):
        result = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--scale", bad, "--seed", "1",
                                          "--run-dir", "unused"])
        assert result.exit_code == 1 and "the scale must be in (0, 1]" in result.output


def test_a_run_directory_in_use_is_refused_at_once_and_freed_when_its_holder_dies(tmp_path):
    """Two recipe processes on one folder would write over each other's checkpoints: the
    second fails at once, naming the holder; a holder killed with SIGKILL leaves no stale lock."""
    import signal
    import subprocess
    import sys

    from formic_world.files import held_directory

    run_dir = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from formic_world.files import held_directory\n"
        f"with held_directory({str(run_dir)!r}):\n    print('held', flush=True); time.sleep(60)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        result = CliRunner().invoke(cli, ["train", "--recipe", "smoke", "--seed", "1", "--run-dir", str(run_dir)])
        assert result.exit_code == 1 and result.output.count("\n") == 1, result.output
        assert f"{run_dir} is in use by another process (pid {holder.pid})" in result.output
        assert not (run_dir / "recipe.json").exists()  # refused before anything was written
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait(timeout=10)
    with held_directory(run_dir):
        assert (run_dir / ".lock").read_text() == f"{os.getpid()}\n"


def test_train_tables_trains_every_row_once_and_skips_a_row_another_process_holds(tmp_path):
    """scripts/train_tables.sh: the reference row, then one row per switch of the recipe; a row
    whose folder another process holds is skipped (two queues share the rows), THREADS reaches
    `--threads`, and a last pass finds every row done and trains nothing."""
    import subprocess

    from formic_world.files import held_directory

    runs = tmp_path / "runs"

    def train_tables(**env: str) -> list[str]:
        done = subprocess.run([str(ROOT / "scripts" / "train_tables.sh"), str(runs)], capture_output=True,
                              text=True, timeout=300, env={**os.environ, "RECIPE": "smoke", "SCALE": "1", **env})
        assert done.returncode == 0, done.stdout + done.stderr
        return [line for line in done.stdout.splitlines() if not line.endswith(".log)")]

    with held_directory(runs / "blind"):
        assert train_tables() == [f"reference: done ({runs}/reference/model.pt)",
                                  "blind: another process is training it, skipped",
                                  f"all-learn: done ({runs}/all-learn/model.pt)"]
    assert not (runs / "blind" / "model.pt").exists()
    assert train_tables(THREADS="2") == [f"reference: done ({runs}/reference/model.pt)",
                              f"blind: done ({runs}/blind/model.pt)",
                              f"all-learn: done ({runs}/all-learn/model.pt)"]
    logs = {name: (runs / f"{name}.log").read_text() for name in ("reference", "blind", "all-learn")}
    assert train_tables() == [f"{name}: done ({runs}/{name}/model.pt)" for name in logs]
    assert {name: (runs / f"{name}.log").read_text() for name in logs} == logs
    assert json.loads((runs / "blind" / "recipe.json").read_text())["switch"] == "blind"
    assert load_train_config(runs / "blind" / "last" / "config.json").threads == 2  # THREADS: --threads 2
    assert load_train_config(runs / "all-learn" / "last" / "config.json").threads == 1


def guarded_smoke(tmp_path: Path) -> Path:
    """The smoke recipe with a fall guard from its first stage on (every set watched, a window of
    one set), its second stage started from the first's best.pt and that stage's best.pt a candidate."""
    recipe = tmp_path / "guarded.toml"
    recipe.write_text(SMOKE_TEXT.replace("checkpoint_every = 1\n", "checkpoint_every = 1\nguard_drop = 0.99\n"
                                         "guard_window = 1\n", 1)
                      .replace('start = "first"', 'start = "first.best"', 1)
                      .replace('candidates = ["middle.mean", "last.mean"]', 'candidates = ["middle.best", "last.mean"]'))
    return recipe


def test_a_stage_starts_from_the_best_checkpoint_its_guarded_predecessor_kept(tmp_path):
    recipe = load_recipe(str(guarded_smoke(tmp_path)))
    run_dir = tmp_path / "run"
    lines: list[str] = []
    run_recipe(recipe, run_dir, seed=1, echo=lines.append)
    assert "stage 2/3 middle: 4 episodes from first.best (a fresh optimiser)" in "\n".join(lines)
    assert load_train_config(run_dir / "middle" / "config.json").init_weights == str(run_dir / "first" / "best.pt")
    for stage in ("first", "middle", "last"):  # every stage's best.pt: its guard's best rolling food
        guard = read_checkpoint(run_dir / stage / "latest.pt")["progress"]["guard"]
        best = read_checkpoint(run_dir / stage / "best.pt")["progress"]
        assert best["episode"] == guard["best_episode"] and best["guard"]["best"] == guard["best"]
    selection = json.loads((run_dir / "selection.json").read_text())
    assert selection["candidates"]["middle.best"]["file"] == str(run_dir / "middle" / "best.pt")
    assert weights_file(run_dir, "middle.best") == run_dir / "middle" / "best.pt"


def test_the_guarded_recipe_is_the_paper_recipe_with_guards_within_five_cpu_hours():
    """recipes/paper-v2.toml: the stages of docs/training.md, "The guarded recipe (paper-v2)",
    and its CPU estimate from paper.toml's measured clock per episode within its budget."""
    v2, paper = load_recipe("paper-v2"), load_recipe("paper")
    assert [(s.name, s.episodes, s.start, s.average) for s in v2.stages] == [
        ("basics", 300, "scratch", None), ("reference", 640, "basics", None), ("crowd", 240, "reference.best", None),
        ("nonlearning", 208, "crowd.best", (96, 8)), ("novalid", 304, "nonlearning.mean", (208, 8)),
        ("novalid128", 208, "novalid.mean", (112, 8))]
    assert v2.stages[0] == paper.stages[0]
    assert (v2.candidates, v2.validation, v2.switches) == (paper.candidates, paper.validation, ())
    configs = {s.name: stage_config(v2, i, Path("run"), seed=1) for i, s in enumerate(v2.stages)}
    reference, crowd = configs["reference"], configs["crowd"]
    assert (reference.filter_anneal_start, reference.filter_anneal_end, reference.filter_final) == (0, 480, 0.0)
    assert (reference.guard_drop, reference.guard_after, reference.target_kl) == (0.6, 480, 0.01)
    assert filter_probability(reference, 480) == 0.0  # the guard watches unfiltered episodes only
    assert all(filter_probability(crowd, e) == 0.0 for e in range(0, 240, 4))
    assert (crowd.guard_drop, crowd.guard_after, crowd.lr, crowd.target_kl, crowd.curriculum) == \
        (0.5, 0, 1e-4, 0.01, False)
    assert [configs[name].guard_drop for name in ("nonlearning", "novalid", "novalid128")] == [None, None, None]
    cpu_seconds = {"basics": 7.7, "reference": 7.7, "crowd": 18, "nonlearning": 4.7, "novalid": 3.9, "novalid128": 4.6}
    hours = sum(cpu_seconds[s.name] * s.episodes for s in v2.stages) / 3600 + 0.4  # validation: ~0.4 h
    assert hours == pytest.approx(4.48, abs=0.01) and hours <= v2.budget_cpu_hours == 5.0
    assert "1, 2, 3, 4, 5, 6, 7, 8" in v2.text
    parsed = cli.commands["train"].make_context("train", ["--recipe", "paper-v2", "--seed", "1", "--run-dir", "X"])
    assert (parsed.params["recipe"], parsed.params["seed"]) == ("paper-v2", 1)


def test_the_third_version_guards_the_whole_reference_stage_and_hands_on_its_unfiltered_best():
    """recipes/paper-v3.toml is paper-v2 with the reference stage's guard watching from episode 0
    and its record restarting at the filter's end (480); nothing else differs."""
    v2, v3 = load_recipe("paper-v2"), load_recipe("paper-v3")
    assert [(s.name, s.episodes, s.start, s.average) for s in v3.stages] == \
        [(s.name, s.episodes, s.start, s.average) for s in v2.stages]
    assert (v3.candidates, v3.validation) == (v2.candidates, v2.validation)
    differ = {}
    for i, stage in enumerate(v3.stages):
        new, old = stage_config(v3, i, Path("run"), seed=1), stage_config(v2, i, Path("run"), seed=1)
        differ[stage.name] = {k: (getattr(old, k), getattr(new, k)) for k in new.to_dict()
                              if getattr(new, k) != getattr(old, k)}
    assert differ["reference"] == {"guard_after": (480, 0), "guard_restart": (None, 480)}
    assert all(not changes for name, changes in differ.items() if name != "reference")
    assert "1, 2, 3, 4, 5, 6, 7, 8" in v3.text


def test_the_fourth_version_puts_the_reference_stages_wheels_on_the_schedule_clock():
    """recipes/paper-v4.toml is paper-v3 with the reference stage 800 episodes long, its filter and
    highways over 600 schedule episodes on a clock that holds at 0.85 x the recent peak, the
    guard's restart at 600; its basics stage is paper-v3's (so v3's basics stages are reused)."""
    v3, v4 = load_recipe("paper-v3"), load_recipe("paper-v4")
    assert [(s.name, s.episodes, s.start, s.average) for s in v4.stages] == \
        [(s.name, 800 if s.name == "reference" else s.episodes, s.start, s.average) for s in v3.stages]
    assert (v4.candidates, v4.validation) == (v3.candidates, v3.validation)
    assert v4.stages[0] == v3.stages[0]
    differ = {}
    for i, stage in enumerate(v4.stages):
        new, old = stage_config(v4, i, Path("run"), seed=1), stage_config(v3, i, Path("run"), seed=1)
        differ[stage.name] = {k: (getattr(old, k), getattr(new, k)) for k in new.to_dict()
                              if getattr(new, k) != getattr(old, k)}
    assert differ["reference"] == {"filter_anneal_end": (480, 600), "curriculum_end": (480, 600),
                                   "anneal_hold": (None, 0.85), "guard_restart": (480, 600),
                                   "total_episodes": (640, 800)}
    # the later stages inherit the highways' end, inert there (no curriculum from the crowd stage on)
    assert all(changes == {"curriculum_end": (480, 600)} for name, changes in differ.items()
               if name not in ("basics", "reference"))
    assert not any(stage_config(v4, i, Path("run"), seed=1).curriculum for i in range(2, len(v4.stages)))
    cpu_seconds = {"basics": 7.7, "reference": 7.7, "crowd": 18, "nonlearning": 4.7, "novalid": 3.9, "novalid128": 4.6}
    hours = sum(cpu_seconds[s.name] * s.episodes for s in v4.stages) / 3600 + 0.4  # validation: ~0.4 h
    assert hours == pytest.approx(4.82, abs=0.01) and hours <= v4.budget_cpu_hours == 5.0
    assert "1, 2, 3, 4, 5, 6, 7, 8" in v4.text


def costed_smoke(tmp_path: Path, schedule_end: int = 0) -> Path:
    """The smoke recipe with planned costs (CPU-seconds per episode: first 10, middle 20, last 30,
    a validation episode 5) and a first stage of 10 episodes, long enough to measure its own
    (with ``schedule_end``, ending on its clock there)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    recipe = tmp_path / "costed.toml"
    text = SMOKE_TEXT if not schedule_end else (  # the middle stage's mean needs its own end: no clock there
        SMOKE_TEXT.replace("checkpoint_every = 1\n", f"checkpoint_every = 1\nschedule_end = {schedule_end}\n", 1)
        .replace("learning_agents = 1\n", "learning_agents = 1\nschedule_end = 0\n", 1))
    recipe.write_text(text.replace('episodes = 4\nstart = "scratch"', 'episodes = 10\nstart = "scratch"\ncost = 10')
                      .replace('start = "first"', 'start = "first"\ncost = 20')
                      .replace('start = "middle.mean"', 'start = "middle.mean"\ncost = 30')
                      .replace("steps = 128", "steps = 128\ncost = 5"))
    return recipe


def test_the_fifth_version_ends_the_reference_stage_on_the_clock():
    """recipes/paper-v5.toml is paper-v4 with the reference stage ending when its schedule clock
    reaches 700 (the fade's 600 and 100 unfiltered), capped at 1,200 episodes; those say only where
    it stops (resumable), so paper-v4's reference stages are its first 800 episodes."""
    v4, v5 = load_recipe("paper-v4"), load_recipe("paper-v5")
    assert [(s.name, s.episodes, s.start, s.average) for s in v5.stages] == \
        [(s.name, 1200 if s.name == "reference" else s.episodes, s.start, s.average) for s in v4.stages]
    assert (v5.candidates, v5.validation) == (v4.candidates, v4.validation)
    assert trained(v5.stages[0]) == trained(v4.stages[0])  # the same basics stage (its planned cost aside)
    differ = {}
    for i, stage in enumerate(v5.stages):
        new, old = stage_config(v5, i, Path("run"), seed=1), stage_config(v4, i, Path("run"), seed=1)
        differ[stage.name] = {k: (getattr(old, k), getattr(new, k)) for k in new.to_dict()
                              if getattr(new, k) != getattr(old, k)}
    assert differ["reference"] == {"schedule_end": (None, 700), "total_episodes": (800, 1200)}
    assert set(differ["reference"]) <= RESUMABLE
    assert all(not changes for name, changes in differ.items() if name != "reference")
    cpu_seconds = {"basics": 5.8, "reference": 5.4, "crowd": 11.3, "nonlearning": 4.7, "novalid": 3.9, "novalid128": 4.6}
    assert {s.name: s.cost for s in v5.stages} == cpu_seconds
    hours = sum(cpu_seconds[s.name] * s.episodes for s in v5.stages) / 3600 + 0.4  # validation: ~0.4 h
    assert hours == pytest.approx(4.30, abs=0.01) and hours <= v5.budget_cpu_hours == 5.0
    assert "1, 2, 3, 4, 5, 6, 7, 8" in v5.text


def test_the_sixth_version_drops_the_bound_on_each_updates_policy_change():
    """recipes/paper-v6.toml is paper-v5 with target_kl off from the reference stage on; nothing
    else differs (its basics stage is paper-v5's)."""
    v5, v6 = load_recipe("paper-v5"), load_recipe("paper-v6")
    assert [(trained(a), a.cost) for a in v6.stages[:1]] == [(trained(b), b.cost) for b in v5.stages[:1]]
    assert [(s.name, s.episodes, s.start, s.average, s.cost) for s in v6.stages] == \
        [(s.name, s.episodes, s.start, s.average, s.cost) for s in v5.stages]
    assert (v6.candidates, v6.validation) == (v5.candidates, v5.validation)
    for i, stage in enumerate(v6.stages):
        new, old = stage_config(v6, i, Path("run"), seed=1), stage_config(v5, i, Path("run"), seed=1)
        differ = {k: (getattr(old, k), getattr(new, k)) for k in new.to_dict() if getattr(new, k) != getattr(old, k)}
        assert differ == ({} if stage.name == "basics" else {"target_kl": (0.01, None)}), stage.name
    assert "1, 2, 3, 4, 5, 6, 7, 8" in v6.text


def test_a_stage_that_ends_on_its_clock_hands_on_and_is_complete_on_resume(tmp_path):
    """The smoke recipe's first stage ends at schedule episode 2 of its 10 (no hold: the clock is
    the episode count); the next stage starts from it, and a second run skips it as complete."""
    recipe = tmp_path / "clocked.toml"
    recipe.write_text(SMOKE_TEXT.replace('episodes = 4\nstart = "scratch"', 'episodes = 10\nstart = "scratch"', 1)
                      .replace("checkpoint_every = 1\n", "checkpoint_every = 1\nschedule_end = 2\n", 1)
                      .replace("learning_agents = 1\n", "learning_agents = 1\nschedule_end = 0\n", 1))
    run_dir, lines = tmp_path / "run", []
    run_recipe(load_recipe(str(recipe)), run_dir, seed=1, echo=lines.append)
    assert read_checkpoint(run_dir / "first" / "latest.pt")["progress"]["episode"] == 2
    assert read_checkpoint(run_dir / "middle" / "latest.pt")["progress"]["episode"] == 4
    for stage in ("first", "middle", "last"):  # the counters a finished run keeps without its checkpoints
        assert json.loads((run_dir / stage / "progress.json").read_text()) == \
            json.loads(json.dumps(read_checkpoint(run_dir / stage / "latest.pt")["progress"]))
    again: list[str] = []
    (run_dir / "selection.json").unlink()  # its choice undone: not a finished run, every stage is looked at
    run_recipe(load_recipe(str(recipe)), run_dir, seed=1, echo=again.append)
    assert "stage 1/3 first: complete (2 episodes), skipped" in again
    bad = tmp_path / "bad.toml"
    bad.write_text(SMOKE_TEXT.replace("checkpoint_every = 1\n", "checkpoint_every = 1\nschedule_end = 2\n", 1))
    with pytest.raises(RecipeError, match="stage 'middle': a mean needs the stage's last episode known"):
        load_recipe(str(bad))


def test_the_time_left_is_each_stages_measured_cost_after_eight_episodes_else_its_planned_one(tmp_path):
    """Stages of 10, 4 and 4 episodes at 10, 20 and 30 CPU-s planned; the validation plays 2
    episodes (2 team sizes x 1 scenario) for each of 2 candidates and once more with the channel
    empty: 6 x 5 = 30 CPU-s."""
    from formic_trainer.recipes.run import RecipeRun

    recipe = load_recipe(str(costed_smoke(tmp_path)))
    assert [s.cost for s in recipe.stages] == [10.0, 20.0, 30.0] and recipe.validation.cost == 5.0
    rest = 4 * 20 + 4 * 30 + 30  # the stages after the first, and the validation
    assert cpu_seconds_left(recipe, 0) == 10 * 10 + rest
    assert cpu_seconds_left(recipe, 0, 7, 700.0) == 3 * 10 + rest  # 7 episodes: still the planned cost
    assert cpu_seconds_left(recipe, 0, 8, 160.0) == 2 * 20 + rest  # 8 episodes: its measured 20 per episode
    assert cpu_seconds_left(recipe, 1, 2, 1000.0) == 2 * 20 + 4 * 30 + 30
    assert cpu_seconds_left(recipe, 3) == 30 and cpu_seconds_left(recipe, 3, validated=True) == 0
    assert cpu_seconds_left(recipe, 3, with_pheromones=False) == 20  # no channel-empty replay
    assert cpu_seconds_left(SMOKE, 0) is None  # no planned costs: no time left shown
    clocked = load_recipe(str(costed_smoke(tmp_path / "clocked", schedule_end=6)))
    assert cpu_seconds_left(clocked, 0, 2, 20.0) == 4 * 10 + rest  # the first stage ends at clock 6 of its 10
    run = RecipeRun(recipe, tmp_path / "run", 1, print)
    run.episodes, run.cpu_seconds = 10, 720.0  # the first stage done
    assert run.budget(1, 2, 1440.0) == "recipe 12/18 episodes, 0.60/0.0 CPU-h (over budget), ~0.1 CPU-h left"
    assert run.budget(3) == "recipe 10/18 episodes, 0.20/0.0 CPU-h (over budget), ~0.0 CPU-h left"
    assert RecipeRun(SMOKE, tmp_path / "plain", 1, print).budget(0, 2, 36.0) == "recipe 2/12 episodes, 0.01/0.0 CPU-h"


def test_planned_costs_are_not_part_of_a_runs_identity(tmp_path):
    """A run claimed by a recipe without costs resumes under the same recipe with them, and the
    committed paper runs (seed 1's claim holds the text of paper.toml before costs existed) still
    resume under today's paper.toml; striking the costs from either paper recipe changes nothing
    it trains."""
    import shutil
    import tomllib

    from formic_trainer.recipes.files import held_identity
    from formic_trainer.recipes.parse import parse_recipe
    from formic_trainer.recipes.run import RecipeRun

    costed = load_recipe(str(costed_smoke(tmp_path)))
    without = tmp_path / "without.toml"
    without.write_text(re.sub(r"(?m)^cost = .*\n", "", costed.text))
    assert load_recipe(str(without)).identity == costed.identity
    RecipeRun(load_recipe(str(without)), tmp_path / "run", 1, print)
    RecipeRun(costed, tmp_path / "run", 1, print)  # accepted
    for name in ("paper", "paper-v2"):
        recipe = load_recipe(name)
        assert all(stage.cost for stage in recipe.stages) and recipe.validation.cost == 6.0
        bare = re.sub(r"(?m)^cost = .*\n", "", recipe.text)
        assert bare != recipe.text
        assert parse_recipe(tomllib.loads(bare), recipe.source, bare).identity == recipe.identity
    claim = ROOT / "models" / "training" / "recipe-paper" / "seed1" / "recipe.json"
    held = json.loads(claim.read_text())
    assert "identity" not in held and "cost =" not in held["text"]
    assert held_identity(held) == load_recipe("paper").identity
    (tmp_path / "seed1").mkdir()
    shutil.copy(claim, tmp_path / "seed1" / "recipe.json")
    RecipeRun(load_recipe("paper"), tmp_path / "seed1", 1, print)  # accepted
