"""Training recipes: every stage of a model, warm starts, checkpoint means and the final choice,
in one resumable command (``formic train --recipe NAME --seed S --run-dir DIR``).

A recipe is a TOML file (``recipes/NAME.toml``, in the spirit of rl-baselines3-zoo's
hyper-parameter files) so that a shipped model is rebuilt from a file instead of from a model
card's hand-run commands. Each stage trains with :class:`~formic_trainer.train.Trainer` in
``DIR/<stage>``; its settings are the previous stage's with its own ``set`` on top (so a stage
reads as "the one before with these switches"), its start is ``"scratch"``, an earlier stage's
final weights, its checkpoint mean or its fall guard's best checkpoint, always with a fresh optimiser. The
candidates named by ``candidates`` are played on validation scenarios stored in ``DIR`` (never
on a test set) and the best by :data:`SELECTION_RULE` is copied to ``DIR/model.pt``.

A kill at any point loses at most the episodes since the last checkpoint: a complete stage is
skipped, a stage in progress resumes from its ``latest.pt``, snapshots, means, ``model.pt`` and
``selection.json`` are written atomically (a mean is rebuilt unless it names exactly its
inputs), and validation episodes are reused from their crash-safe log.
"""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from formic_agent.checkpoint import read_checkpoint
from formic_world.errors import InputError
from formic_world.files import atomic_open, held_directory

from .averaging import average_sources, write_average
from .config import PRESETS, TrainConfig, make_config
from .train import Trainer, export_model

RECIPES = Path(__file__).resolve().parents[2] / "recipes"
SELECTION_RULE = ("the candidate with the highest mean food over all validation episodes (every team size "
                  "pooled, agents sampling); the first listed wins a tie")
# TrainConfig fields a stage's `set` may not hold: the recipe derives them
DERIVED = {"preset": "the recipe's preset", "seed": "--seed", "total_episodes": "the stage's episodes",
           "init_weights": "the stage's start"}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
# TrainConfig (start, end) schedules counted in a stage's episodes: a scaled recipe scales them
SCHEDULES = (("filter_anneal_start", "filter_anneal_end"), ("curriculum_start", "curriculum_end"))
# ... and the episode the fall guard starts watching at
EPISODE_SETTINGS = ("guard_after",)
# a stage reference's part -> the file in the stage's folder: "NAME", "NAME.mean", "NAME.best"
WEIGHTS = {"": "latest.pt", "mean": "mean.pt", "best": "best.pt"}
# a stage's own CPU clock per episode replaces its planned `cost` once it has run this many episodes
MEASURED_AFTER = 8


class RecipeError(InputError):
    """A recipe (or a run directory) that cannot be used, with the reason in one line."""


@dataclass(frozen=True)
class Stage:
    name: str
    episodes: int
    start: str  # "scratch", an earlier stage's name (its final weights), "<stage>.mean" or "<stage>.best"
    settings: dict  # every TrainConfig field this stage sets, inherited ones included
    average: tuple[int, int] | None  # (first, every): the mean of the checkpoints first, first+every, ..., episodes
    cost: float | None = None  # planned CPU-seconds per episode (the progress line's time left; not identity)

    def snapshots(self) -> tuple[int, ...]:
        """The episodes whose weights the stage's mean averages."""
        return () if self.average is None else tuple(range(self.average[0], self.episodes + 1, self.average[1]))


@dataclass(frozen=True)
class Validation:
    """The validation set: ``scenarios`` per team size, generated like ``formic eval --seed``."""

    seed: int
    size: int
    teams: tuple[int, ...]
    scenarios: int
    steps: int
    cost: float | None = None  # planned CPU-seconds per validation episode (not identity)

    @property
    def episodes(self) -> int:
        """Episodes one model plays on the validation set."""
        return self.scenarios * len(self.teams)


@dataclass(frozen=True)
class Recipe:
    source: Path
    text: str
    preset: str
    budget_cpu_hours: float
    stages: tuple[Stage, ...]
    candidates: tuple[str, ...]
    validation: Validation
    switch: str = ""  # the switch applied to every stage ("" = the recipe as written)
    switches: tuple[str, ...] = ()  # every switch the file defines
    scale: float = 1.0  # every scaled stage's episodes, means and schedules times this (an equal, smaller budget)

    @property
    def episodes(self) -> int:
        return sum(stage.episodes for stage in self.stages)

    @property
    def identity(self) -> str:
        """What a run of this recipe trains and how it chooses, as canonical JSON: a run
        directory resumes only under the same identity (comments, the budget line and other
        switches and the planned costs may change in between)."""
        return json.dumps({"preset": self.preset, "stages": [_trained(stage) for stage in self.stages],
                           "candidates": self.candidates, "validation": _trained(self.validation)},
                          sort_keys=True)


def _trained(part: Stage | Validation) -> dict:
    """A stage or the validation as a run's identity holds it: without its planned cost."""
    return {key: value for key, value in asdict(part).items() if key != "cost"}


def recipe_path(spec: str) -> Path:
    """A recipe name (``recipes/NAME.toml`` of this repository) or a ``.toml`` file."""
    path = Path(spec)
    return path if path.suffix == ".toml" or len(path.parts) > 1 else RECIPES / f"{spec}.toml"


def load_recipe(spec: str, switch: str = "", scale: float = 1.0) -> Recipe:
    """Read and check a recipe, with one of its switches (``[switch.NAME]``: settings laid over
    every stage, e.g. one row of the paper's ablation tables) when ``switch`` names one, and
    every stage's episodes, checkpoint means and episode schedules times ``scale`` (in (0, 1]:
    rows of a table at one smaller budget), but for a stage marked ``scaled = false``, and the
    budget times the share of episodes kept. Every stage's configuration is built once here, so
    a mistake fails before any training, in one line naming the file."""
    if not 0 < scale <= 1:
        raise RecipeError(f"the scale must be in (0, 1], not {scale}")
    path = recipe_path(spec)
    try:
        text = path.read_text()
    except OSError as exc:
        known = ", ".join(sorted(p.stem for p in RECIPES.glob("*.toml")))
        raise RecipeError(f"{path}: cannot read ({exc.strerror}); recipes here: {known}") from None
    try:
        return _parse(tomllib.loads(text), path, text, switch, scale)
    except tomllib.TOMLDecodeError as exc:
        raise RecipeError(f"{path}: not valid TOML ({exc})") from None
    except (TypeError, ValueError) as exc:  # RecipeError, or a TrainConfig's own check
        raise RecipeError(f"{path}: {exc}") from None


def _keys(table: dict, where: str, required: set[str], optional: set[str] = frozenset()) -> dict:
    if not isinstance(table, dict):
        raise RecipeError(f"{where} must be a table")
    missing, unknown = sorted(required - set(table)), sorted(set(table) - required - optional)
    if missing:
        raise RecipeError(f"{where}: missing {', '.join(missing)}")
    if unknown:
        raise RecipeError(f"{where}: unknown {', '.join(unknown)} (known: {', '.join(sorted(required | optional))})")
    return table


def _typed(value, like, where: str, length: int | None = None):
    """``value`` from TOML as the type of ``like`` (a TrainConfig default): lists become tuples,
    inner ones (a world's side range) as long as the default's."""
    if isinstance(like, tuple):
        if not isinstance(value, list) or length not in (None, len(value)):
            raise RecipeError(f"{where} must be a list" + (f" of {length}" if length else ""))
        inner = len(like[0]) if isinstance(like[0], tuple) else None
        return tuple(_typed(v, like[0], f"{where}[{i}]", inner) for i, v in enumerate(value))
    if isinstance(like, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if type(value) is not type(like):
        raise RecipeError(f"{where} must be {type(like).__name__}, not {value!r}")
    return value


def _number(table: dict, key: str, where: str, kind: type = int, least: float = 1):
    value = table[key]
    if kind is float and type(value) is int:
        value = float(value)
    if type(value) is not kind or value < least:
        raise RecipeError(f"{where}.{key} must be {'a whole number' if kind is int else 'a number'} >= {least}, "
                          f"not {value!r}")
    return value


def _settings(table: dict, where: str, defaults: TrainConfig) -> dict:
    """A ``set`` table as TrainConfig values (only fields a recipe may set)."""
    if not isinstance(table, dict):
        raise RecipeError(f"{where} must be a table")
    known, settings = {f.name for f in fields(TrainConfig)}, {}
    for key, value in table.items():
        if key not in known:
            raise RecipeError(f"{where}.{key} is not a training setting (a TrainConfig field)")
        if key in DERIVED:
            raise RecipeError(f"{where}.{key}: given by {DERIVED[key]}")
        settings[key] = _typed(value, getattr(defaults, key), f"{where}.{key}")
    return settings


def _switch_settings(data: dict, switch: str, defaults: TrainConfig) -> tuple[dict, tuple[str, ...]]:
    """The chosen switch's settings (empty for none) and the names of every switch."""
    switches = data.get("switch", {})
    if not isinstance(switches, dict):
        raise RecipeError("switch must be a table of [switch.NAME] tables")
    for name, table in switches.items():
        if not _NAME.fullmatch(name):
            raise RecipeError(f"switch {name!r}: a name of letters, digits, - and _")
        _keys(table, f"switch {name!r}", {"about", "set"})
        _settings(table["set"], f"switch {name!r}.set", defaults)
    if switch and switch not in switches:
        raise RecipeError(f"no switch {switch!r} (switches: {', '.join(switches) or 'none'})")
    chosen = _settings(switches[switch]["set"], f"switch {switch!r}.set", defaults) if switch else {}
    return chosen, tuple(switches)


def _scaled(count: int, scale: float, unit: int) -> int:
    """``count * scale`` to the nearest multiple of ``unit`` (at least one unit)."""
    return max(unit, unit * round(count * scale / unit))


def _scaled_schedules(cfg: TrainConfig, scale: float) -> dict:
    """Every schedule's start and end (and every episode setting not 0) times ``scale``; one that has
    an end after its start keeps one (an end equal to the start means "no schedule", e.g. the
    filter held on)."""
    out = {key: round(getattr(cfg, key) * scale) for key in EPISODE_SETTINGS if getattr(cfg, key)}
    for start_key, end_key in SCHEDULES:
        start, end = getattr(cfg, start_key), getattr(cfg, end_key)
        out[start_key] = round(start * scale)
        out[end_key] = max(round(end * scale), out[start_key] + 1) if end > start else out[start_key]
    return out


def _parse(data: dict, path: Path, text: str, switch: str = "", scale: float = 1.0) -> Recipe:
    _keys(data, "recipe", {"preset", "budget_cpu_hours", "candidates", "validation", "stage"}, {"switch"})
    if data["preset"] not in PRESETS:
        raise RecipeError(f"preset {data['preset']!r} is not one of {', '.join(PRESETS)}")
    defaults = TrainConfig()
    switched, switch_names = _switch_settings(data, switch, defaults)
    stages: list[Stage] = []
    settings: dict = {}
    full_episodes = 0
    if not isinstance(data["stage"], list) or not data["stage"]:
        raise RecipeError("needs one or more [[stage]] tables")
    for i, table in enumerate(data["stage"]):
        _keys(table, f"stage {i + 1}", {"name", "episodes", "start"}, {"set", "average", "scaled", "cost"})
        name, start = table["name"], table["start"]
        where = f"stage {name!r}"
        earlier = {s.name: s for s in stages}
        if not isinstance(name, str) or not _NAME.fullmatch(name) or name == "scratch" or name in earlier:
            raise RecipeError(f"stage {i + 1}: name {name!r} must be new, not 'scratch', of letters, digits, - and _")
        if start != "scratch":
            _reference(start, earlier, f"{where}: start", data["preset"])
        settings |= _settings(table.get("set", {}), f"{where}.set", defaults)
        staged = settings | switched  # a switch holds in every stage, over the stage's own settings
        try:
            cfg = make_config(data["preset"], **staged)
        except (TypeError, ValueError) as exc:
            raise RecipeError(f"{where}: {exc}") from None
        worlds, episodes = len(cfg.teams), _number(table, "episodes", where)
        average = None
        if "average" in table:
            _keys(table["average"], f"{where}.average", {"first", "every"})
            average = (_number(table["average"], "first", f"{where}.average"),
                       _number(table["average"], "every", f"{where}.average"))
            if average[0] > episodes:
                raise RecipeError(f"{where}.average.first ({average[0]}) is beyond its {episodes} episodes")
        if any(n % worlds for n in (episodes, *(average or ()))):
            raise RecipeError(f"{where}: episodes and average must be multiples of its {worlds} worlds "
                              "(one episode set plays one episode in each)")
        scaled = table.get("scaled", True)
        if type(scaled) is not bool:
            raise RecipeError(f"{where}.scaled must be true or false, not {scaled!r}")
        full_episodes += episodes
        if scale != 1 and scaled:
            episodes = _scaled(episodes, scale, worlds)
            if average is not None:
                average = (min(_scaled(average[0], scale, average[1]), episodes), average[1])
            staged = staged | _scaled_schedules(cfg, scale)
        stages.append(Stage(name, episodes, start, staged, average, _cost(table, where)))
    candidates = data["candidates"]
    if not isinstance(candidates, list) or not candidates or len(set(candidates)) < len(candidates):
        raise RecipeError("candidates must be a list of distinct stages or stage means")
    for candidate in candidates:
        _reference(candidate, {s.name: s for s in stages}, "candidates", data["preset"])
    table = _keys(data["validation"], "validation", {"seed", "size", "teams", "scenarios", "steps"}, {"cost"})
    teams = table["teams"]
    if not isinstance(teams, list) or not teams or not all(type(n) is int and n > 0 for n in teams):
        raise RecipeError("validation.teams must be a list of team sizes")
    validation = Validation(_number(table, "seed", "validation", least=0), _number(table, "size", "validation"),
                            tuple(teams), _number(table, "scenarios", "validation"),
                            _number(table, "steps", "validation"), _cost(table, "validation"))
    budget = _number(data, "budget_cpu_hours", "recipe", float, 0) * sum(s.episodes for s in stages) / full_episodes
    return Recipe(path, text, data["preset"], budget, tuple(stages), tuple(candidates), validation, switch,
                  switch_names, scale)


def _cost(table: dict, where: str) -> float | None:
    """A table's optional ``cost``: planned CPU-seconds per episode, above 0."""
    cost = table.get("cost")
    if cost is None:
        return None
    if type(cost) not in (int, float) or cost <= 0:
        raise RecipeError(f"{where}.cost must be a number > 0 (CPU-seconds per episode), not {cost!r}")
    return float(cost)


def cpu_seconds_left(recipe: Recipe, index: int, episode: int = 0, cpu_seconds: float = 0.0,
                     validated: bool = False, with_pheromones: bool = True) -> float | None:
    """The CPU-seconds a run still needs with stage ``index`` in progress at ``episode``, having
    spent ``cpu_seconds`` on it (the stages before it done, those after it not started; ``index``
    = the number of stages: all done): each unfinished stage's episodes left at its measured cost
    per episode once it has run :data:`MEASURED_AFTER` episodes, else at its planned ``cost``; and
    the validation's planned cost (every candidate, and the chosen one again with the pheromone
    channel empty when the recipe trains ``with_pheromones``) unless ``validated``. None where a
    cost is needed and the recipe plans none."""
    left = 0.0
    for i, stage in enumerate(recipe.stages[index:], start=index):
        done = episode if i == index else 0
        cost = cpu_seconds / done if done >= MEASURED_AFTER else stage.cost
        if done < stage.episodes:
            if cost is None:
                return None
            left += (stage.episodes - done) * cost
    if not validated:
        v = recipe.validation
        if v.cost is None:
            return None
        left += v.cost * v.episodes * (len(recipe.candidates) + with_pheromones)
    return left


def _reference(ref: str, stages: dict[str, Stage], where: str, preset: str) -> None:
    """``ref`` names an (earlier) stage's final weights, its mean when it has one, or its best
    checkpoint when its fall guard is on."""
    name, _, part = ref.partition(".") if isinstance(ref, str) else ("", "", "")
    if name not in stages or part not in WEIGHTS or (part == "mean" and stages[name].average is None):
        raise RecipeError(f"{where} {ref!r} is not 'scratch', an earlier stage, the '.mean' of an earlier "
                          f"stage with an average or the '.best' of an earlier stage with a fall guard "
                          f"(stages: {', '.join(stages) or 'none'})")
    if part == "best" and make_config(preset, **stages[name].settings).guard_drop <= 0:
        raise RecipeError(f"{where} {ref!r}: stage {name!r} keeps no best.pt, its fall guard is off "
                          "(set its guard_drop)")


def weights_file(run_dir: Path, ref: str) -> Path:
    """The file a stage reference names: ``DIR/<stage>/latest.pt``, ``mean.pt`` or ``best.pt``."""
    name, _, part = ref.partition(".")
    return run_dir / name / WEIGHTS[part]


def stage_config(recipe: Recipe, index: int, run_dir: Path, seed: int, threads: int | None = None) -> TrainConfig:
    """Stage ``index``'s training configuration; its seed is 1000 * seed + index + 1, so no two
    stages of a run and no two runs of seeds below 1000 share a random stream. ``threads``
    replaces the stage's torch threads (speed only: a stage may resume with another count)."""
    stage = recipe.stages[index]
    start = "" if stage.start == "scratch" else str(weights_file(run_dir, stage.start))
    settings = stage.settings if threads is None else {**stage.settings, "threads": threads}
    return make_config(recipe.preset, **settings, seed=1000 * seed + index + 1,
                       total_episodes=stage.episodes, init_weights=start)


def _progress(checkpoint: Path) -> dict:
    """The counters of a stage's ``latest.pt`` (zero before it exists)."""
    if not checkpoint.exists():
        return {"episode": 0, "cpu_seconds": 0.0}
    progress = read_checkpoint(checkpoint)["progress"]
    return {"episode": progress["episode"], "cpu_seconds": progress.get("cpu_seconds", progress["seconds"])}


def shown_recipe(source: Path) -> str:
    """A recipe's file as a claim records it: ``recipes/NAME.toml`` for this repository's recipes
    (a committed run holds no machine's paths), the path as given otherwise."""
    try:
        return str(Path(source).resolve().relative_to(RECIPES.parent))
    except ValueError:
        return str(source)


def held_identity(held: dict) -> str:
    """A claim's identity; claims written before identities existed hold the recipe's text."""
    if "identity" in held:
        return held["identity"]
    return _parse(tomllib.loads(held["text"]), Path(held["recipe"]), held["text"]).identity


def _write_json(path: Path, data: dict) -> None:
    with atomic_open(path) as handle:
        handle.write(json.dumps(data, indent=2) + "\n")


def run_recipe(recipe: Recipe, run_dir: Path, seed: int, echo: Callable[[str], None] = print,
               threads: int | None = None) -> Path:
    """Run (or resume) every stage of ``recipe`` in ``run_dir``, then choose the model on
    validation; returns ``run_dir/model.pt``. The run holds ``run_dir`` throughout: a second
    process on the same folder fails at once. ``threads``: torch threads for every stage and
    processes for validation, instead of the recipe's (how fast, not what is trained: not part of
    the run's identity, so a run may resume with another count)."""
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be at least 1, not {threads}")
    with held_directory(run_dir):
        run = _Run(recipe, Path(run_dir), seed, echo, threads)
        for index in range(len(recipe.stages)):
            run.stage(index)
        return run.select()


class _Run:
    """One run of a recipe: its directory, and the budget it has spent (for the progress lines)."""

    def __init__(self, recipe: Recipe, run_dir: Path, seed: int, echo: Callable[[str], None],
                 threads: int | None = None):
        self.recipe, self.run_dir, self.seed, self.echo, self.threads = recipe, run_dir, seed, echo, threads
        self.trainer: Trainer | None = None  # the trainer of the stage in progress
        self.episodes, self.cpu_seconds = 0, 0.0  # of the stages finished
        claim = run_dir / "recipe.json"  # a folder holds one run: a skipped or resumed stage is this recipe's
        held = json.loads(claim.read_text()) if claim.exists() else None
        if held is None:
            _write_json(claim, {"recipe": shown_recipe(recipe.source), "seed": seed, "switch": recipe.switch,
                                "scale": recipe.scale, "identity": recipe.identity, "text": recipe.text})
        elif (held["seed"], held_identity(held)) != (seed, recipe.identity):
            raise RecipeError(f"{run_dir} holds a run of another recipe, switch, scale or seed ({claim}): "
                              "use a new --run-dir")

    def budget(self, index: int, episode: int = 0, cpu_seconds: float = 0.0) -> str:
        """The progress line's budget with stage ``index`` at ``episode`` after ``cpu_seconds``
        (``index`` = the number of stages: the run is over, validation included): episodes
        done, CPU-hours spent and, where the costs are known, the CPU-hours left."""
        recipe = self.recipe
        hours, budget = (self.cpu_seconds + cpu_seconds) / 3600, recipe.budget_cpu_hours
        with_pheromones = make_config(recipe.preset, **recipe.stages[-1].settings).pheromones
        left = cpu_seconds_left(recipe, index, episode, cpu_seconds, index == len(recipe.stages), with_pheromones)
        return (f"recipe {self.episodes + episode}/{recipe.episodes} episodes, {hours:.2f}/{budget:.1f} CPU-h"
                f"{' (over budget)' if hours > budget else ''}"
                f"{'' if left is None else f', ~{left / 3600:.1f} CPU-h left'}")

    def stage(self, index: int) -> None:
        """Train stage ``index`` to its end in chunks that stop at every episode its mean
        needs (a snapshot of the weights is taken there), then write the mean."""
        stage, count = self.recipe.stages[index], len(self.recipe.stages)
        where = self.run_dir / stage.name
        progress = _progress(where / "latest.pt")
        episode = progress["episode"]
        if episode >= stage.episodes:
            self.echo(f"stage {index + 1}/{count} {stage.name}: complete ({stage.episodes} episodes), skipped")
        else:
            fresh = "" if stage.start == "scratch" else " (a fresh optimiser)"
            resume = f", resuming at episode {episode}" if episode else ""
            resume += f", {self.threads} torch thread(s)" if self.threads else ""
            self.echo(f"stage {index + 1}/{count} {stage.name}: {stage.episodes} episodes from {stage.start}{fresh}"
                      f"{resume} | {self.budget(index, episode, progress['cpu_seconds'])}")
            cfg = stage_config(self.recipe, index, self.run_dir, self.seed, self.threads)
            while episode < stage.episodes:
                self.snapshot(stage, episode)
                self.trainer = None  # while it starts: its lines carry no budget yet
                self.trainer = Trainer(cfg, where, log=lambda line: self.log(index, line))
                stop = min([e for e in stage.snapshots() if e > episode] + [stage.episodes])
                self.trainer.train(episodes=stop - episode)
                episode = self.trainer.episode
            self.trainer = None
        self.snapshot(stage, episode)
        if stage.average is not None:
            self.average(stage)
        wanted = {s.start for s in self.recipe.stages} | set(self.recipe.candidates)
        if f"{stage.name}.best" in wanted and not (where / "best.pt").exists():
            raise RecipeError(f"{where}: no best.pt, which {stage.name}.best names: its fall guard never saw "
                              "guard_window episode sets after guard_after")
        self.episodes += stage.episodes
        self.cpu_seconds += _progress(where / "latest.pt")["cpu_seconds"]

    def log(self, index: int, line: str) -> None:
        trainer = self.trainer
        budget = "" if trainer is None else " | " + self.budget(index, trainer.episode, trainer.learner.cpu_seconds)
        self.echo(f"{self.recipe.stages[index].name}: {line}{budget}")

    def snapshot_file(self, stage: Stage, episode: int) -> Path:
        return self.run_dir / stage.name / "snapshots" / f"episode{episode:05d}.pt"

    def snapshot(self, stage: Stage, episode: int) -> None:
        """Keep the weights of ``episode`` when the stage's mean needs them (once)."""
        target = self.snapshot_file(stage, episode)
        if episode in stage.snapshots() and not target.exists():
            export_model(self.run_dir / stage.name / "latest.pt", target)

    def average(self, stage: Stage) -> None:
        """Write the stage's mean unless ``mean.pt`` already names exactly its snapshots."""
        where = self.run_dir / stage.name
        inputs = [self.snapshot_file(stage, e) for e in stage.snapshots()]
        missing = [p.name for p in inputs if not p.exists()]
        if missing:
            raise RecipeError(f"{where}: the mean needs {', '.join(missing)}, which this run did not keep")
        mean = where / "mean.pt"
        if mean.exists() and read_checkpoint(mean).get("averaged_from") == average_sources(inputs):
            return
        write_average(inputs, mean)
        self.echo(f"{stage.name}: mean.pt = the mean of episodes {', '.join(map(str, stage.snapshots()))}")

    def select(self) -> Path:
        """Play every candidate on the validation scenarios, copy the best to ``model.pt`` and
        play it once more with the pheromone channel empty; ``selection.json`` has it all."""
        v, folder = self.recipe.validation, self.run_dir / "validation"
        matrix = validation_matrix(v, folder / "scenarios")
        # a model trained without pheromones is tested without them too (the paper's Table I row)
        blind = not self.trains_with_pheromones()
        scores = {name: self.validate(matrix, weights_file(self.run_dir, name), folder / name, no_pheromones=blind)
                  for name in self.recipe.candidates}
        chosen = max(self.recipe.candidates, key=lambda name: scores[name]["food_mean"])
        model = self.run_dir / "model.pt"
        with atomic_open(model, "wb") as handle:
            handle.write(weights_file(self.run_dir, chosen).read_bytes())
        empty = (scores[chosen] if blind else
                 self.validate(matrix, model, folder / f"{chosen}-channel-empty", no_pheromones=True))
        sampled = scores[chosen]["food_by_team"]
        less = {n: 1 - empty["food_by_team"][n] / sampled[n] if sampled[n] else 0.0 for n in sampled}
        _write_json(self.run_dir / "selection.json", {
            "rule": SELECTION_RULE, "validation": _trained(v) | {"scenarios_dir": str(folder / "scenarios")},
            "candidates": scores, "chosen": chosen, "model": str(model),
            "channel_empty": empty | {"less_by_team": less},
            "episodes": self.recipe.episodes, "cpu_hours": self.cpu_seconds / 3600})
        self.echo(f"model: {model} = {chosen} (validation food: "
                  + ", ".join(f"{name} {s['food_mean']:.1f}" for name, s in scores.items()) + ")")
        self.echo(f"validation (seed {v.seed}: {v.size}x{v.size}, {v.steps} steps, {v.scenarios} per team size, "
                  "sampling): agents / food / channel empty / less")
        for n in sampled:
            self.echo(f"  {n:4d}  {sampled[n]:8.1f}  {empty['food_by_team'][n]:8.1f}  {less[n]:5.0%}")
        self.echo(self.budget(len(self.recipe.stages)))
        return model

    def trains_with_pheromones(self) -> bool:
        """Whether the recipe's agents see the pheromone channel (every stage does the same)."""
        stages = range(len(self.recipe.stages))
        seen = {stage_config(self.recipe, i, self.run_dir, self.seed).pheromones for i in stages}
        if len(seen) > 1:
            raise RecipeError("stages differ in `pheromones`: the validation cannot test them alike")
        return seen.pop()

    def validate(self, matrix: dict, model: Path, out: Path, no_pheromones: bool = False) -> dict:
        """``model`` on the validation scenarios; their one-thread episode clock joins the CPU budget."""
        self.echo(f"validation: {model}{' (pheromone channel empty)' if no_pheromones else ''} -> {out}")
        score = play_validation(matrix, model, out, no_pheromones, workers=self.threads or 1)
        self.cpu_seconds += score["cpu_seconds"]
        return {key: value for key, value in score.items() if key != "cpu_seconds"}


def validation_matrix(validation: Validation, folder: Path) -> dict:
    """The validation scenarios, written into (or kept in) ``folder``: 128x128-style worlds of
    ``validation``'s size, infinite resources, no obstacles, one setting per team size."""
    from formic_eval import generate_matrix, settings_grid

    v = validation
    grid = settings_grid([v.size], v.teams, [0.0], ["infinite"], v.steps)
    return generate_matrix(grid, v.scenarios, v.seed, folder)


def play_validation(matrix: dict, model: Path, out: Path, no_pheromones: bool = False, workers: int = 1) -> dict:
    """``model`` on ``matrix`` (episodes kept in ``out``, reused when there) in ``workers``
    one-thread processes: its file, digest, episodes, mean food over them all and per team size,
    and the episodes' CPU seconds."""
    from formic_eval import PolicyOptions, evaluate
    from formic_eval.matrix import file_digest
    from formic_eval.runner import folder_episodes

    options = PolicyOptions(model=str(model), model_digest=file_digest(model), no_pheromones=no_pheromones)
    summary = evaluate(matrix, ["formic"], options, out, workers=workers, source=str(out.parent / "scenarios"))
    if summary["interrupted"]:
        raise KeyboardInterrupt
    cells = summary["cells"]
    n = sum(c["n"] for c in cells)
    return {"file": str(model), "digest": options.model_digest, "episodes": n,
            "food_mean": sum(c["n"] * c["food_mean"] for c in cells) / n,
            "food_by_team": {c["agents"]: c["food_mean"] for c in cells},
            "cpu_seconds": sum(record["wall_s"] for record in folder_episodes(out))}
