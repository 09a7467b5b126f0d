"""The ``formic`` command line. Each subcommand prints a short human summary and, with
``--json``, one JSON object on stdout. Heavy imports happen inside the commands so that
``formic --help`` stays instant."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from formic_agent.inputs import NETWORK_PRESETS
from formic_world.config import TEST_EPISODE_STEPS
from formic_world.errors import InputError
from formic_world.limits import MAX_EPISODE_STEPS

from .options import (EPISODE_STEPS, POSITIVE, SEED, SIDE, TEAM, OutputFolder, comma_list, fresh_option, json_option,
                      live_view_port, model_option, open_live_view, preset_option, scenario_from, team_options,
                      view_options, world_config_from, world_option_group, world_options)
from .summary import click_errors, emit, emit_json, print_episode_summary


class FormicGroup(click.Group):
    """Every subcommand runs through :meth:`invoke`: input the user gave that cannot be used
    (:class:`~formic_world.errors.InputError`, raised by the loaders of scenarios and models or
    by a resumed run's checks, wherever they are called) ends the command with one line on
    stderr and exit status 1 instead of a traceback."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except InputError as exc:
            raise click.ClickException(str(exc)) from exc


@click.group(cls=FormicGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="formic-ros")
def cli() -> None:
    """ForMIC: multi-agent foraging with learned pheromone communication."""
    from formic_runtime.memory import keep_freed_memory

    keep_freed_memory()  # a forward pass no longer faults its buffers back in every step


@cli.command()
@world_options
@team_options
@click.option("--out", type=OutputFolder(), default="out/sim", show_default=True,
              help="Where the final picture (and --gif) go.")
@click.option("--gif", is_flag=True, help="Also write an animation of the episode.")
@view_options()
@json_option()
def sim(policy, model, greedy, scenario_file, out, gif, live_view, view_port, view_wait, as_json,
        **world_kw) -> None:
    """One episode in one process, no ROS (the same result as `formic run`)."""
    from contextlib import nullcontext

    from formic_runtime.episode import run_episode
    from formic_runtime.registry import world_overrides
    from formic_runtime.team import Team
    from formic_runtime.threads import configure_threads
    from formic_world.render import render_frame, render_frames_to_file, save_png

    port = live_view_port(live_view, view_port, view_wait)
    scenario = scenario_from(scenario_file, world_kw)
    configure_threads()
    frames = []
    view = open_live_view(port, wait=view_wait) if port is not None else None

    def on_step(w) -> None:
        if gif:
            frames.append(render_frame(w, scale=3))
        if view is not None:
            view.publish(w, final=w.done)

    with click_errors(ValueError), view if view is not None else nullcontext():
        # in the world the team needs (one-slot queues for csaf-ref), over the scenario's own
        overrides = world_overrides(Team.parse(policy, scenario.config.n_agents).names)
        result = run_episode(scenario, policy, model=model, greedy=greedy,
                             on_step=on_step if gif or view is not None else None)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    picture = out_dir / "final.png"
    save_png(render_frame(result.world, scale=4), picture)
    files = {"picture": str(picture)}
    if gif:
        files["animation"] = str(out_dir / "episode.gif")
        render_frames_to_file(frames, files["animation"])
    summary = result.summary(result.world.scenario, policy)
    if overrides:
        summary["world_overrides"] = overrides
    summary["files"] = files
    if as_json:
        emit_json(summary)
        return
    print_episode_summary(summary)
    if overrides:
        click.echo("world settings of this team: " + ", ".join(f"{k}={v!r}" for k, v in overrides.items()))


@cli.group()
def scenarios() -> None:
    """Generate and inspect stored scenario sets."""


@scenarios.command("generate")
@world_option_group(TEST_EPISODE_STEPS, "Episode length: the paper's test episodes, as `formic eval` runs them "
                    "(512: training's).")
@click.option("--count", type=click.IntRange(min=1), default=50, show_default=True,
              help="Scenarios in the set (seeds seed..seed+count-1).")
@click.option("--out", type=OutputFolder(), required=True, help="Directory for the set.")
@json_option(help=None)
def scenarios_generate(count, out, as_json, **world_kw) -> None:
    """Write COUNT scenarios for one size/team/obstacle setting as plain JSON files."""
    from formic_world.scenario_sets import generate_set

    paths = generate_set(*world_config_from(world_kw), count, Path(out))
    emit(as_json, {"directory": out, "files": [str(p) for p in paths]},
         f"wrote {len(paths)} scenarios to {out}")


@scenarios.command("show")
@click.argument("path", type=click.Path(exists=True))
@json_option(help=None)
def scenarios_show(path, as_json) -> None:
    """Describe a scenario file or a directory of them (and check they load)."""
    from formic_world.scenario_sets import describe, load_set

    items = load_set(Path(path))
    rows = [describe(s) | {"file": str(p)} for p, s in items]
    if as_json:
        emit_json({"scenarios": rows})
        return
    for row in rows:
        click.echo(
            f"{row['file']}: {row['height']}x{row['width']}, {row['agents']} agents, "
            f"{row['resources']} resources ({row['capacity']}), {row['obstacles']} obstacles, "
            f"seed {row['seed']}, wipeouts at {row['wipeout_starts']}"
        )


@cli.command()
@click.argument("source", type=click.Path(exists=True))
@click.option("--out", type=click.Path(dir_okay=False), help="Output file (.png, .gif or .mp4).")
@click.option("--scale", type=click.IntRange(min=1), default=4, show_default=True, help="Pixels a cell.")
@click.option("--fps", type=click.IntRange(1, 240), default=20, show_default=True)
def render(source, out, scale, fps) -> None:
    """Render a scenario file (PNG) or a recording (GIF/MP4)."""
    from formic_world import Scenario, World
    from formic_world.render import render_frame, save_png

    src = Path(source)
    scenario = src.is_file() and src.suffix == ".json"
    suffixes = (".png",) if scenario else (".png", ".gif", ".mp4")
    if out is not None and Path(out).suffix.lower() not in suffixes:
        raise click.BadParameter(f"{out!r}: a {'scenario' if scenario else 'recording'} renders to "
                                 f"{', '.join(suffixes)}", param_hint="'--out'")
    if scenario:
        target = Path(out or src.with_suffix(".png"))
        with click_errors(ValueError):
            save_png(render_frame(World(Scenario.load(src)), scale=scale), target)
    else:
        with click_errors(ImportError, prefix="cannot render recordings: "):
            from formic_record.reading import RecordingError
            from formic_record.replay import render_recording
        target = Path(out or (src.with_suffix(".mp4") if src.is_file() else src / "replay.mp4"))
        with click_errors(RecordingError, ValueError):
            render_recording(src, target, scale=scale, fps=fps)
    click.echo(f"wrote {target}")


@cli.group()
def bench() -> None:
    """Throughput benchmarks (run them on a quiet machine)."""


@bench.command("world")
@click.option("--size", type=SIDE, default=128, show_default=True)
@click.option("--teams", default="16,32,64,128", show_default=True, help="Team sizes, comma list.")
@click.option("--steps", type=EPISODE_STEPS, default=512, show_default=True)
@click.option("--seed", type=SEED, default=0, show_default=True)
@json_option(help=None)
def bench_world(size, teams, steps, seed, as_json) -> None:
    """Steps/s and agent-steps/s of the core with random valid actions, observations included."""
    from formic_world.bench import bench_world as run

    results = [run(size, n, steps, seed) for n in comma_list(teams, TEAM, "--teams")]
    if as_json:
        emit_json({"size": size, "steps": steps, "results": results})
        return
    click.echo(f"world {size}x{size}, {steps} steps, random valid actions, observations included")
    for r in results:
        click.echo(f"  {r['agents']:4d} agents: {r['steps_per_s']:9.0f} steps/s  "
                   f"{r['agent_steps_per_s']:11.0f} agent-steps/s")


@bench.command("policy")
@click.option("--network", type=click.Choice(sorted(NETWORK_PRESETS)), default="cpu", show_default=True,
              help="Network preset.")
@click.option("--batch", type=click.IntRange(min=1), default=128, show_default=True, help="Agents per inference batch.")
@click.option("--threads", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--episodes", type=click.IntRange(min=1), default=1, show_default=True,
              help="Training episode sets to time end to end.")
@json_option(help=None)
def bench_policy(network, batch, threads, episodes, as_json) -> None:
    """Inference agent-steps/s and end-to-end training agent-steps/s."""
    from formic_trainer.bench import bench_policy as run

    result = run(network, batch, threads, episodes)
    if as_json:
        emit_json(result)
        return
    for key, value in result.items():
        click.echo(f"  {key}: {value:,.1f}" if isinstance(value, float) else f"  {key}: {value}")


@bench.command("decide")
@click.option("--size", type=SIDE, default=128, show_default=True)
@click.option("--teams", default="16,32,64,128", show_default=True, help="Team sizes, comma list.")
@click.option("--steps", type=click.IntRange(2, MAX_EPISODE_STEPS), default=50, show_default=True,
              help="Steps per team size (the first, warming caches up, is not timed).")
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--policy", default="formic", show_default=True, help="Team spec (the shipped model for formic).")
@model_option
@click.option("--threads", type=click.IntRange(min=0), default=1, show_default=True,
              help="Torch threads (0: torch's default pool).")
@json_option(help=None)
def bench_decide(size, teams, steps, seed, policy, model, threads, as_json) -> None:
    """In-process decision time per step (as `formic sim` runs) for each team size."""
    from formic_runtime.episode import run_episode
    from formic_runtime.threads import configure_threads
    from formic_world import WorldConfig, generate_scenario

    if threads:
        configure_threads(threads)
    results = []
    for n in comma_list(teams, TEAM, "--teams"):  # step 0 (warming caches up) left out
        config = WorldConfig(height=size, width=size, n_agents=n, episode_steps=steps)
        stats = run_episode(generate_scenario(config, seed), policy, model=model)
        results.append({"agents": n, "decide_ms_per_step": float(stats.decision_seconds[1:].mean() * 1e3),
                        "world_ms_per_step": float(stats.step_seconds[1:].mean() * 1e3)})
    if as_json:
        emit_json({"size": size, "steps": steps, "policy": policy, "threads": threads, "results": results})
        return
    click.echo(f"{policy}, world {size}x{size}, {steps} steps, {threads or 'default'} torch threads")
    for r in results:
        click.echo(f"  {r['agents']:4d} agents: decide {r['decide_ms_per_step']:7.2f} ms/step, "
                   f"world {r['world_ms_per_step']:6.2f} ms/step")


@cli.command()
@preset_option
@click.option("--run-dir", type=OutputFolder(), default="runs/formic", show_default=True)
@click.option("--episodes", type=click.IntRange(min=0), help="Environment episodes to add in this call.")
@click.option("--minutes", type=POSITIVE, help="Stop after this many minutes (checkpoint kept).")
@fresh_option
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a training field, e.g. --set network=cpu-nest --set pheromones=false.")
@click.option("--export", type=click.Path(dir_okay=False),
              help="Afterwards write the weights alone (a small model file) here.")
@click.option("--recipe", help="Run every stage of a recipe (recipes/NAME.toml, or a .toml file) into RUN_DIR "
              "and choose RUN_DIR/model.pt on validation; resumes (docs/training.md).")
@click.option("--seed", type=SEED, help="The recipe's seed (with --recipe; a single run: --set seed=N).")
@click.option("--switch", default="", help="With --recipe: one of its [switch.NAME] tables laid over every "
              "stage (e.g. a row of the paper's ablation tables).")
@click.option("--scale", type=float, default=1.0, show_default=True,
              help="With --recipe: every stage's episodes, means and schedules times this, in (0, 1] "
                   "(table rows at one smaller budget).")
@click.option("--threads", type=click.IntRange(min=1),
              help="With --recipe: torch threads for every stage and processes for its validation, instead of "
                   "the recipe's (speed only; a run may resume with another count).")
@click.option("--status", is_flag=True,
              help="With --recipe: say where the run in RUN_DIR stands (each stage, the validation, the CPU-hours "
                   "spent and left) and train nothing; safe while it trains.")
@click.pass_context
def train(ctx, preset, run_dir, episodes, minutes, fresh, overrides, export, recipe, seed, switch, scale,
          threads, status) -> None:
    """Train a policy; checkpoints to RUN_DIR/latest.pt, TensorBoard logs to RUN_DIR/tb.

    Resumes from RUN_DIR/latest.pt when it exists. Ctrl-C (or SIGTERM) stops after the episode
    set in progress and saves the checkpoint; a second one stops at once. `--episodes 0 --export
    FILE` only exports."""
    if recipe is not None or seed is not None or switch or scale != 1 or threads is not None or status:
        _train_recipe(ctx, recipe, seed, switch, scale, threads, Path(run_dir), status)
        return
    from formic_runtime.signals import STOP_SIGNALS, FirstStopInterrupts, handling
    from formic_trainer.config import make_config, parse_overrides
    from formic_trainer.train import Trainer, export_model

    with click_errors(TypeError, ValueError):
        cfg = make_config(preset, **parse_overrides(overrides))
    if episodes != 0:
        resume = f"interrupted: rerun the same command to resume from {Path(run_dir) / 'latest.pt'}"
        with click_errors(interrupted=resume), handling(STOP_SIGNALS, FirstStopInterrupts()):
            Trainer(cfg, Path(run_dir), resume=not fresh, log=click.echo).train(episodes=episodes, minutes=minutes)
    if export:
        export_model(Path(run_dir) / "latest.pt", Path(export))
        click.echo(f"exported {export}")


def _train_recipe(ctx: click.Context, recipe: str | None, seed: int | None, switch: str, scale: float,
                  threads: int | None, run_dir: Path, status: bool = False) -> None:
    """`formic train --recipe`: the recipe sets every stage, so the single-run options are refused."""
    from click.core import ParameterSource

    from formic_runtime.signals import STOP_SIGNALS, FirstStopInterrupts, handling
    from formic_trainer.recipes.files import load_recipe
    from formic_trainer.recipes.run import run_recipe, run_status

    single_run = {"preset": "--preset", "episodes": "--episodes", "minutes": "--minutes", "fresh": "--fresh",
                  "overrides": "--set", "export": "--export"}
    given = [flag for name, flag in single_run.items() if ctx.get_parameter_source(name) is not ParameterSource.DEFAULT]
    if recipe is None or seed is None:
        raise click.UsageError("--recipe and --seed go together (a single run's seed: --set seed=N)")
    if given:
        raise click.UsageError(f"--recipe sets every stage itself: drop {', '.join(given)}")
    if status:
        with click_errors(TypeError, ValueError):
            click.echo("\n".join(run_status(load_recipe(recipe, switch, scale), run_dir, seed)))
        return
    with (click_errors(TypeError, ValueError, interrupted="interrupted: rerun the same command to resume"),
          handling(STOP_SIGNALS, FirstStopInterrupts())):  # SIGTERM as Ctrl-C; a stage stops between episode sets
        run_recipe(load_recipe(recipe, switch, scale), run_dir, seed, echo=click.echo, threads=threads)


def _register_optional() -> None:
    """Commands from packages that may be absent in a partial install (e.g. no ROS)."""
    for module in ("formic_cli.eval_commands", "formic_cli.ros_commands", "formic_cli.ros_record_commands",
                   "formic_cli.actor_commands"):
        try:
            mod = __import__(module, fromlist=["register"])
        except ImportError as exc:
            if exc.name and exc.name.startswith("formic_cli."):
                continue
            raise
        mod.register(cli)


_register_optional()

if __name__ == "__main__":
    sys.exit(cli())
