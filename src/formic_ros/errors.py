"""The errors a node command reports as its own (a message and a non-zero exit, no traceback):
shared by the world, the drivers and the commands that start them."""


class RunError(RuntimeError):
    """A run that cannot go on as asked: the node command says so and exits non-zero."""


class NobodyJoined(RunError):
    """No agent answered step 0 within the start-up timeout (and running empty was not asked for)."""


class WorldLost(RunError):
    """The world left the graph before the episode a ``--once`` process plays had ended."""
