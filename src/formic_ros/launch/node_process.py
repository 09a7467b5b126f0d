"""One node process of a launched run: ``python -m formic_ros.launch.node_process --options FILE``.

The launcher writes each child's options as JSON (``{"node": KIND, "kwargs": {...}}``) next to
the run's scenario; this loads them and calls the ``serve_*`` function the hand-written
``formic world | agents | planner | record | trainer`` commands call, so no command line is
built and parsed again. The world and the trainer print their results on stdout, one JSON
object a line. Ctrl-C (SIGINT) ends a node with status 130. A node's own error (a
:class:`RunError`, a file that does not load, a bad value) ends it with status 1 and its message
in ``NAME.error`` beside the options file, where the launcher reads it to tell the user in one
line (:meth:`Child.error <formic_ros.launch.processes.Child.error>`).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from formic_runtime.json_output import emit_json as emit  # what `formic world --json` prints
from formic_runtime.signals import STOP_SIGNALS


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def world(options: dict, domain_id: int | None, scenario: str | None = None, train_config: str | None = None,
          episodes: int = 1, first_episode: int = 0, world_index: int | None = None) -> None:
    """One episode on ``scenario`` (a file), or training mode: ``episodes`` on ``train_config``'s."""
    from ..world.serve import serve_world
    from ..world.options import WorldNodeOptions

    options = WorldNodeOptions(**{k: tuple(v) if isinstance(v, list) else v for k, v in options.items()})
    if train_config is None:
        from formic_world import Scenario

        serve_world(Scenario.load(scenario), options, domain_id=domain_id, on_summary=emit, scenario_file=scenario)
        return
    from formic_trainer.config import load_train_config

    from ..world.training import serve_training_world

    serve_training_world(load_train_config(train_config), episodes, options, first_episode=first_episode,
                         domain_id=domain_id, on_episode=emit, world_index=world_index)


def agents(**kwargs) -> None:
    from ..drivers.agent_host import serve_agents

    serve_agents(**kwargs)


def learning_agents(train_config: str, **kwargs) -> None:
    from formic_trainer.config import load_train_config

    from ..drivers.learning_host import serve_learning_agents

    serve_learning_agents(cfg=load_train_config(train_config), **kwargs)


def planner(**kwargs) -> int:
    from ..drivers.planner import serve_planner

    mismatches = serve_planner(**kwargs)
    if mismatches:
        log(f"the planner's replica differed from the world {mismatches} time(s)")
    return 1 if mismatches else 0


def recorder(out: str, model: str | None, domain_id: int | None, **options) -> None:
    from formic_agent.checkpoint import checkpoint_id

    from ..recording.recorder import RecorderOptions, record

    if Path(out).exists():
        raise FileExistsError(f"{out} exists; a recording is never written over")
    options = RecorderOptions(**options, checkpoint_id=checkpoint_id(model) if model else "")
    record(out, options, domain_id=domain_id, on_ready=lambda node: log(f"recording to {out}"))


def trainer(train_config: str, run_dir: str, **kwargs) -> None:
    from formic_trainer.config import load_train_config

    from ..drivers.trainer import serve_trainer

    emit(serve_trainer(load_train_config(train_config), Path(run_dir), log=log, **kwargs))


def robots(settings: dict, **kwargs) -> None:
    """Robot bridges (``formic robot``): ``settings`` are a :class:`BridgeSettings`' fields."""
    from formic_robots.controller import ControllerSettings

    from ..robots.bridge import serve_robots
    from ..robots.settings import BridgeSettings

    controller = ControllerSettings(**settings.pop("controller"))
    serve_robots(settings=BridgeSettings(**settings, controller=controller), **kwargs)


def robots_sim(settings: dict, **kwargs) -> None:
    """The robot simulator (``formic robots-sim``): ``settings`` are a :class:`SimSettings`' fields."""
    from formic_robots.unicycle import UnicycleLimits

    from ..robots.settings import SimSettings
    from ..robots.sim import serve_robots_sim

    limits = UnicycleLimits(**settings.pop("limits"))
    serve_robots_sim(settings=SimSettings(**{**settings, "origin": tuple(settings["origin"])}, limits=limits),
                     **kwargs)


NODES = {f.__name__: f for f in (world, agents, learning_agents, planner, recorder, trainer, robots, robots_sim)}


def node_spec(node: str, **kwargs) -> dict:
    """What the launcher writes for one child: the node kind and its function's arguments."""
    if node not in NODES:
        raise ValueError(f"unknown node {node!r}")
    return {"node": node, "kwargs": kwargs}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m formic_ros.launch.node_process",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--options", required=True, help="The node's options (JSON), as the launcher writes them.")
    options = Path(parser.parse_args(argv).options)
    spec = json.loads(options.read_text())
    from formic_runtime.memory import keep_freed_memory
    from formic_world.errors import InputError

    keep_freed_memory()  # as every `formic` command does

    from ..errors import RunError

    try:
        try:
            code = NODES[spec["node"]](**spec["kwargs"]) or 0
        finally:
            leaving()
    except KeyboardInterrupt:
        code = 130
    except (RunError, InputError, ValueError, FileNotFoundError, FileExistsError) as exc:
        # e.g. a model file that does not load, a resume with other settings, robots outside the team
        error_file(options).write_text(str(exc))
        code = 1
    sys.exit(code)


def leaving() -> None:
    """Ignore the stop signals once the node has stopped: a stop that reaches a process already
    on its way out (the launcher stops every child when one fails, and another may be ending on
    its own) would otherwise interrupt the interpreter's exit with a KeyboardInterrupt traceback
    (once seen inside ``logging.shutdown``). SIGKILL still ends one that hangs. Not a signal mask:
    a stop delivered to one of the process's other threads (DDS, torch) would still interrupt."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def error_file(options: Path) -> Path:
    """Where a child launched on ``options`` (``DIR/NAME.options.json``) leaves its error message."""
    return options.with_name(options.name.replace(".options.json", ".error"))


if __name__ == "__main__":
    main()
