"""A recipe's TOML tables to a checked :class:`~.definition.Recipe`: every key known, every
value typed like its TrainConfig field, every stage reference resolvable, and ``--scale``
applied to episodes, means and episode schedules."""

from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

from ..config import PRESETS, TrainConfig, make_config, typed_example
from .definition import WEIGHTS, Recipe, RecipeError, Stage, Validation

# TrainConfig fields a stage's `set` may not hold: the recipe derives them
DERIVED = {"preset": "the recipe's preset", "seed": "--seed", "total_episodes": "the stage's episodes",
           "init_weights": "the stage's start"}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
# TrainConfig (start, end) schedules counted in a stage's episodes: a scaled recipe scales them
SCHEDULES = (("filter_anneal_start", "filter_anneal_end"), ("curriculum_start", "curriculum_end"))
# ... and the episodes the fall guard starts watching at and restarts at, and the clock's end
EPISODE_SETTINGS = ("guard_after", "guard_restart", "schedule_end")


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
    """``value`` from TOML as the type of ``like`` (a TrainConfig default, or its off spelling:
    TOML has no None): lists become tuples, inner ones (a world's side range) as long as the default's."""
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
        settings[key] = _typed(value, typed_example(defaults, key), f"{where}.{key}")
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
    """Every schedule's start and end (and every episode setting not 0 or None) times ``scale``; one that has
    an end after its start keeps one (an end equal to the start means "no schedule", e.g. the
    filter held on)."""
    out = {key: round(getattr(cfg, key) * scale) for key in EPISODE_SETTINGS if getattr(cfg, key)}
    for start_key, end_key in SCHEDULES:
        start, end = getattr(cfg, start_key), getattr(cfg, end_key)
        out[start_key] = round(start * scale)
        out[end_key] = max(round(end * scale), out[start_key] + 1) if end > start else out[start_key]
    return out


def parse_recipe(data: dict, path: Path, text: str, switch: str = "", scale: float = 1.0) -> Recipe:
    """A recipe from its TOML tables (``path`` and ``text`` are what it was read from)."""
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
            if cfg.schedule_end is not None:
                raise RecipeError(f"{where}: a mean needs the stage's last episode known, so no schedule_end "
                                  "(set schedule_end = 0 in this stage)")
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




def _reference(ref: str, stages: dict[str, Stage], where: str, preset: str) -> None:
    """``ref`` names an (earlier) stage's final weights, its mean when it has one, or its best
    checkpoint when its fall guard is on."""
    name, _, part = ref.partition(".") if isinstance(ref, str) else ("", "", "")
    if name not in stages or part not in WEIGHTS or (part == "mean" and stages[name].average is None):
        raise RecipeError(f"{where} {ref!r} is not 'scratch', an earlier stage, the '.mean' of an earlier "
                          f"stage with an average or the '.best' of an earlier stage with a fall guard "
                          f"(stages: {', '.join(stages) or 'none'})")
    if part == "best" and make_config(preset, **stages[name].settings).guard_drop is None:
        raise RecipeError(f"{where} {ref!r}: stage {name!r} keeps no best.pt, its fall guard is off "
                          "(set its guard_drop)")
