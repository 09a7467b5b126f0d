"""``formic eval``: the paper's evaluation matrix (SPEC §8) for any list of algorithms."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click

from formic_world.config import PHEROMONE_VARIANTS

from .options import EPISODE_STEPS, OBSTACLES, SIDE, TEAM, OutputFolder, comma_list, json_option
from .summary import click_errors, emit

DEFAULT_ALGORITHMS = "formic,planner,csaf,csaf11,cardinality"
DEFAULT_SIZES, DEFAULT_TEAMS, DEFAULT_OBSTACLES = "128", "16,32,64,128", "0,0.05"
DEFAULT_ENVS = "infinite,finite,wipeout"


@click.command("eval")
@click.option("--algorithms", default=DEFAULT_ALGORITHMS, show_default=True,
              help="Comma list of formic, planner, csaf, csaf11, cardinality, random, and the reference "
                   "variants csaf-ref, csaf11-ref.")
@click.option("--sizes", help=f"World sides, comma list [default: {DEFAULT_SIZES}].")
@click.option("--teams", help=f"Team sizes, comma list [default: {DEFAULT_TEAMS}].")
@click.option("--obstacles", help=f"Obstacle densities, comma list [default: {DEFAULT_OBSTACLES}].")
@click.option("--env", "envs", help=f"Environments: comma list of infinite, finite (respawning), "
              f"wipeout (infinite, 3 x 100-step wipeouts; steps//4 below 400 steps) [default: {DEFAULT_ENVS}].")
@click.option("--scenarios", default="50", show_default=True,
              help="Scenarios per setting, generated into OUT/scenarios; or a directory of stored "
                   "scenario files (their settings, filtered by the options above when given).")
@click.option("--seed", default=0, show_default=True, help="Seed the scenario seeds derive from.")
@click.option("--steps", type=EPISODE_STEPS, help="Episode length [default: 1024, the paper's test "
              "length; with a scenario directory, the files' length].")
@click.option("--out", type=OutputFolder(), default="out/eval", show_default=True,
              help="Results directory; rerunning the same command there resumes.")
@click.option("--model", type=click.Path(dir_okay=False), help="Checkpoint of the formic policy.")
@click.option("--greedy", is_flag=True, help="The learned policy takes its most likely action.")
@click.option("--no-pheromones", is_flag=True,
              help="The learned policy sees an empty pheromone channel (the paper's ablation).")
@click.option("--variant", "pheromone_variant", type=click.Choice(PHEROMONE_VARIANTS), default="standard",
              show_default=True, help="Pheromone variant of every world, the paper's out-of-distribution "
              "tests: flat (decaying trails without gradient), noisy (locally noisy gradient), random "
              "(random concentration 0.2-1).")
@click.option("--workers", default=2, show_default=True, type=click.IntRange(1),
              help="Episodes run in parallel processes (1: in this process; fairest for timings).")
@click.option("--report", "report_only", is_flag=True,
              help="Run nothing: rebuild results, figures and results.md from every episode in OUT.")
@click.option("--seed-eval", "seed_evals", multiple=True, type=click.Path(file_okay=False, exists=True),
              help="With --report, repeated: the evaluation folders of one recipe's seeds (one model each). "
                   "Instead of rebuilding OUT, print the statistics over these seeds on Fig. 5's cells, "
                   "against the baselines' episodes in OUT on the same scenarios.")
@json_option()
@click.pass_context
def eval_command(ctx, algorithms, sizes, teams, obstacles, envs, scenarios, seed, steps, out, model, greedy,
                 no_pheromones, pheromone_variant, workers, report_only, seed_evals, as_json) -> None:
    """Run every algorithm on the same stored scenarios; write CSV/JSON results, figures and
    OUT/results.md (ours beside the paper's numbers). Interrupt with Ctrl-C and rerun to resume."""
    if seed_evals and not report_only:
        raise click.UsageError("--seed-eval goes with --report")
    if seed_evals:
        _report_seeds(Path(out), [Path(folder) for folder in seed_evals], as_json)
        return
    if report_only:
        from formic_eval.runner import report_everything

        summary = report_everything(Path(out))
        if "report" not in summary["files"]:
            raise click.ClickException(f"{out}: no episodes to report (formic eval --out {out} plays them)")
        emit(as_json, summary, f"report: {summary['files']['report']}")
        return
    from formic_eval import evaluate, generate_matrix, load_matrix, settings_grid
    from formic_eval.matrix import ENVIRONMENTS
    from formic_eval.paper import PAPER_STEPS
    from formic_eval.runner import EpisodeError
    from formic_runtime.registry import POLICY_NAMES
    from formic_world import ScenarioError

    names = comma_list(algorithms, str, "--algorithms", POLICY_NAMES)
    # None: every setting of a scenario directory, or the defaults for generated scenarios
    size_list = comma_list(sizes, SIDE, "--sizes") if sizes is not None else None
    team_list = comma_list(teams, TEAM, "--teams") if teams is not None else None
    obstacle_list = comma_list(obstacles, OBSTACLES, "--obstacles") if obstacles is not None else None
    env_list = comma_list(envs, str, "--env", ENVIRONMENTS) if envs is not None else None

    options = dataclasses.replace(_policy_options(names, model, greedy, no_pheromones),
                                  pheromone_variant=pheromone_variant)
    out_dir = Path(out)
    with click_errors(ScenarioError, ValueError, prefix="scenarios: "):
        if scenarios.strip().isdigit():
            count = int(scenarios)
            if count < 1:
                raise click.BadParameter("needs at least one scenario", param_hint="'--scenarios'")
            grid = settings_grid(size_list or comma_list(DEFAULT_SIZES, SIDE, "--sizes"),
                                 team_list or comma_list(DEFAULT_TEAMS, TEAM, "--teams"),
                                 obstacle_list or comma_list(DEFAULT_OBSTACLES, OBSTACLES, "--obstacles"),
                                 env_list or comma_list(DEFAULT_ENVS, str, "--env"), steps or PAPER_STEPS)
            source = out_dir / "scenarios"
            matrix = generate_matrix(grid, count, seed, source)
        elif Path(scenarios).is_dir():
            source = Path(scenarios)
            matrix = load_matrix(source, size_list, team_list, obstacle_list, env_list, steps)
        else:
            raise click.BadParameter(f"{scenarios!r} is neither a count nor a directory", param_hint="'--scenarios'")
    if not matrix:
        raise click.ClickException(f"no scenarios in {scenarios} match the selected settings")
    try:
        summary = evaluate(matrix, names, options, out_dir, workers=workers, source=str(source))
    except EpisodeError as exc:
        raise click.ClickException(f"episode failed ({exc}); finished episodes are kept, rerun to resume") from exc
    emit(as_json, summary, _print_summary)
    if summary["interrupted"]:
        ctx.exit(130)


def _report_seeds(baselines_folder: Path, folders: list[Path], as_json: bool) -> None:
    """The statistics over seeds (``formic_eval.seeds_report``): each folder's ForMIC episodes
    by the paper's protocol, named by the folder, against OUT's C-SAF-11 and Cardinality-MR."""
    import dataclasses as dc

    from formic_eval.paper import RIVALS, test_set_episodes
    from formic_eval.runner import folder_episodes
    from formic_eval.seeds import study
    from formic_eval.seeds_report import seeds_report

    names = [folder.name for folder in folders]
    if len(set(names)) < len(names):
        raise click.BadParameter(f"two seed folders share a name ({', '.join(names)})", param_hint="'--seed-eval'")
    per_seed = {folder.name: test_set_episodes(folder_episodes(folder), "formic") for folder in folders}
    empty = [name for name, records in per_seed.items() if not records]
    if empty:
        raise click.ClickException(f"no ForMIC test episodes in {', '.join(empty)}")
    everything = folder_episodes(baselines_folder)
    baselines = {algorithm: test_set_episodes(everything, algorithm) for algorithm, _ in RIVALS}
    with click_errors(ValueError):
        result = study(per_seed, baselines)
    lines = seeds_report(result)
    summary = {"out": str(baselines_folder), "seed_evals": [str(f) for f in folders],
               "study": dc.asdict(result), "report": "\n".join(lines)}
    emit(as_json, summary, summary["report"])


def _policy_options(names: list[str], model: str | None, greedy: bool, no_pheromones: bool):
    """Check every algorithm can be built (baseline module present, model file loads: a
    missing or unusable model is an InputError, reported by the ``formic`` group)."""
    from formic_runtime.registry import make_policy, model_path
    from formic_eval import PolicyOptions
    from formic_eval.matrix import file_digest

    for name in names:
        try:
            make_policy(name, model=model, greedy=greedy)
        except ImportError as exc:
            raise click.ClickException(f"algorithm {name} is not available: {exc}") from exc
    if "formic" not in names:
        return PolicyOptions(greedy=greedy, no_pheromones=no_pheromones)
    path = str(model_path(model))
    return PolicyOptions(model=path, model_digest=file_digest(path), greedy=greedy, no_pheromones=no_pheromones)


def _print_summary(summary: dict) -> None:
    episodes = summary["episodes"]
    click.echo(
        f"{episodes['done']}/{episodes['total']} episodes ({episodes['computed']} run now, "
        f"{episodes['reused']} reused) in {summary['wall_s']:.1f} s"
    )
    for c in summary["cells"]:
        name = c["algorithm"] + (f" ({c['variant']})" if c["variant"] else "")
        ratio = "" if c["food_ratio_to_planner"] is None else f"  {c['food_ratio_to_planner']:.2f} x planner"
        paper = "" if c["paper_food"] is None else f"  paper {c['paper_food']:.0f}"
        click.echo(
            f"  {c['size']}x{c['size']} {c['env']:8s} obst {c['obstacles']:<4g} {c['agents']:4d} agents  "
            f"{name:14s} food {c['food_mean']:7.1f} ± {c['food_std']:5.1f} (n={c['n']})  "
            f"{c['step_ms_mean']:8.2f} ms/step{ratio}{paper}"
        )
    if summary["interrupted"]:
        click.echo("interrupted: rerun the same command to resume", err=True)
    for kind, path in summary["files"].items():
        click.echo(f"{kind}: {path}")


def register(cli: click.Group) -> None:
    cli.add_command(eval_command)
