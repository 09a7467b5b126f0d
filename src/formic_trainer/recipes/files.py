"""Where recipes live and how a run records one: the shipped recipes (package data, so a
non-editable install has them too), loading a recipe by name or file, and the run's claim."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from formic_world.files import atomic_open

from .definition import Recipe, RecipeError
from .parse import parse_recipe

SHIPPED = Path(__file__).resolve().parent / "shipped"  # the repository's recipes/ links here


def recipe_path(spec: str) -> Path:
    """A recipe name (``recipes/NAME.toml``, shipped with the package) or a ``.toml`` file."""
    path = Path(spec)
    return path if path.suffix == ".toml" or len(path.parts) > 1 else SHIPPED / f"{spec}.toml"


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
        known = ", ".join(sorted(p.stem for p in SHIPPED.glob("*.toml")))
        raise RecipeError(f"{path}: cannot read ({exc.strerror}); recipes here: {known}") from None
    try:
        return parse_recipe(tomllib.loads(text), path, text, switch, scale)
    except tomllib.TOMLDecodeError as exc:
        raise RecipeError(f"{path}: not valid TOML ({exc})") from None
    except (TypeError, ValueError) as exc:  # RecipeError, or a TrainConfig's own check
        raise RecipeError(f"{path}: {exc}") from None


def shown_recipe(source: Path) -> str:
    """A recipe's file as a claim records it: ``recipes/NAME.toml`` for a shipped recipe (a
    committed run holds no machine's paths, and the repository's ``recipes/`` is that folder),
    the path as given otherwise."""
    try:
        return str(Path("recipes") / Path(source).resolve().relative_to(SHIPPED))
    except ValueError:
        return str(source)


def held_identity(held: dict) -> str:
    """A claim's identity; claims written before identities existed hold the recipe's text."""
    if "identity" in held:
        return held["identity"]
    return parse_recipe(tomllib.loads(held["text"]), Path(held["recipe"]), held["text"]).identity


def write_json(path: Path, data: dict) -> None:
    """``data`` as indented JSON, written atomically (a claim, ``selection.json``)."""
    with atomic_open(path) as handle:
        handle.write(json.dumps(data, indent=2) + "\n")
