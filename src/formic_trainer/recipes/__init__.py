"""Training recipes: every stage of a model, warm starts, checkpoint means and the final choice,
in one resumable command (``formic train --recipe NAME --seed S --run-dir DIR``).

A recipe is a TOML file (``recipes/NAME.toml``, in the spirit of rl-baselines3-zoo's
hyper-parameter files) so that a shipped model is rebuilt from a file instead of from a model
card's hand-run commands. Each stage trains with :class:`~formic_trainer.train.Trainer` in
``DIR/<stage>``; its settings are the previous stage's with its own ``set`` on top (so a stage
reads as "the one before with these switches"), its start is ``"scratch"``, an earlier stage's
final weights, its checkpoint mean or its fall guard's best checkpoint, always with a fresh optimiser. The
candidates named by ``candidates`` are played on validation scenarios stored in ``DIR`` (never
on a test set) and the best by :data:`~formic_trainer.recipes.validation.SELECTION_RULE` is
copied to ``DIR/model.pt``.

A kill at any point loses at most the episodes since the last checkpoint: a complete stage is
skipped, a stage in progress resumes from its ``latest.pt``, snapshots, means, ``model.pt`` and
``selection.json`` are written atomically (a mean is rebuilt unless it names exactly its
inputs), and validation episodes are reused from their crash-safe log.

The modules, in the order a run uses them: :mod:`.files` (where recipes live, loading, the
run's claim), :mod:`.parse` (a TOML table to a checked :class:`~.definition.Recipe`),
:mod:`.definition` (stages, validation, identity, each stage's configuration), :mod:`.run`
(stages, snapshots, means, the progress line) and :mod:`.validation` (the validation set, its
episodes and the choice). The shipped recipes are package data in ``shipped/``; the
repository's ``recipes/`` links there.
"""
