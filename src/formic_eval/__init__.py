"""The evaluation harness behind ``formic eval``: the paper's matrix of settings on stored
scenario sets, every algorithm on the same scenarios, resumable, with CSV/JSON results,
figures and a report beside the paper's published numbers."""

from .matrix import PolicyOptions, Setting, generate_matrix, load_matrix, settings_grid
from .results import aggregate, food_stats
from .runner import evaluate

__all__ = ["PolicyOptions", "Setting", "aggregate", "evaluate", "food_stats", "generate_matrix", "load_matrix",
           "settings_grid"]
