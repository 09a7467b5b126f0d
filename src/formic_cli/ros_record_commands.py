"""``formic record``, ``formic replay`` and ``formic trainer``: recordings and the trainer node.
ROS and torch are imported inside the commands, so ``formic --help`` stays instant."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import click

from .options import hosts_network_option, open_live_view, view_options
from .summary import emit_json

NAMESPACE_HELP = "ROS namespace of the ForMIC topics and nodes."
DOMAIN_HELP = "ROS_DOMAIN_ID for this process (default: the environment's)."

_AGENT_PART = re.compile(r"(?<=/)agent_\d+(?=/|$)")


def grouped_topic_lines(counts: dict[str, int]) -> list[str]:
    """One line per topic, the per-agent topics (``.../agent_<i>/...``) grouped into one line
    with their number and min/max message counts."""
    groups: dict[str, list[int]] = {}
    lines = []
    for topic, count in sorted(counts.items()):
        pattern = _AGENT_PART.sub("agent_*", topic)
        if pattern == topic:
            lines.append(f"{topic}: {count}")
        else:
            groups.setdefault(pattern, []).append(count)
    for pattern, values in sorted(groups.items()):
        lines.append(f"{pattern} ({len(values)} topics): {min(values)}-{max(values)} each"
                     if min(values) != max(values) else f"{pattern} ({len(values)} topics): {values[0]} each")
    return lines



def _log(text: str) -> None:
    click.echo(text, err=True)


def _split(values: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(t.strip() for v in values for t in v.split(",") if t.strip())


# -------------------------------------------------------------------------------- record
@click.command("record")
@hosts_network_option
@click.option("--out", required=True, type=click.Path(file_okay=False),
              help="Recording directory to create (rosbag2 with MCAP storage).")
@click.option("--topics", multiple=True, metavar="TOPIC[,TOPIC]",
              help="Absolute topic names to record (default: every topic in the namespace, and /clock).")
@click.option("--namespace", default="/formic", show_default=True, help=NAMESPACE_HELP)
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--model", type=click.Path(exists=True, dir_okay=False),
              help="Checkpoint the learned agents run: its id is stored with the recording.")
@click.option("--duration", type=float, help="Stop after this many seconds (default: at Ctrl-C or SIGTERM).")
@click.option("--chunk-kb", default=256, show_default=True,
              help="MCAP chunk size; a killed recorder loses at most its last chunk (or 0.5 s).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object at the end.")
def record_command(out, topics, namespace, domain_id, model, duration, chunk_kb, as_json) -> None:
    """Record ForMIC topics into a rosbag2 recording (MCAP) until interrupted."""
    from formic_agent.checkpoint import checkpoint_id
    from formic_ros.recorder import RecorderOptions, record

    if Path(out).exists():
        raise click.ClickException(f"{out} exists; a recording is never written over")
    options = RecorderOptions(namespace=namespace, topics=_split(topics),
                              checkpoint_id=checkpoint_id(model) if model else "", chunk_bytes=chunk_kb * 1024)
    try:
        result = record(out, options, domain_id=domain_id, duration_s=duration,
                        on_ready=lambda node: _log(f"recording to {out} (Ctrl-C to stop)"))
    except ValueError as exc:
        raise click.ClickException(str(exc)) from exc
    if as_json:
        emit_json(result)
        return
    click.echo(f"wrote {result['recording']}: {result['messages']} messages on {len(result['topics'])} topics")
    for line in grouped_topic_lines(result["topics"]):
        click.echo(f"  {line}")
    for topic, why in result["skipped"].items():
        click.echo(f"  not recorded: {topic} ({why})")


# -------------------------------------------------------------------------------- replay
@click.command("replay")
@click.argument("recording", type=click.Path(exists=True))
@click.option("--verify", is_flag=True, help="Re-simulate from the scenario and applied actions; every "
              "recorded state must match bit for bit (exit status 1 if not).")
@click.option("--republish", is_flag=True, help="Publish the recorded topics again on their recorded clock.")
@click.option("--repair", is_flag=True, help="Rebuild the index and metadata.yaml of a recording cut short "
              "(the original file is kept as <name>.mcap.truncated).")
@view_options()
@click.option("--rate", default=1.0, show_default=True,
              help="--republish and --view speed factor (--view: of sim time; 0: as fast as possible).")
@click.option("--topics", multiple=True, metavar="TOPIC[,TOPIC]", help="--republish only these topics.")
@click.option("--wait", default=1.0, show_default=True,
              help="--republish starts once every topic has a subscriber, or after this many seconds.")
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def replay_command(recording, verify, republish, repair, live_view, view_port, view_wait, rate, topics, wait,
                   domain_id, as_json) -> None:
    """Verify, republish, view or repair a recording (without a mode: describe it)."""
    from formic_record.reading import Recording, RecordingError, repair_recording

    if verify + republish + repair + live_view > 1:
        raise click.UsageError("choose one of --verify, --republish, --view, --repair")
    try:
        if live_view:
            from formic_record.replay import view_recording

            view = open_live_view(view_port, wait=view_wait)
            try:
                steps = view_recording(recording, view, rate=rate)
            finally:
                view.close()
            if as_json:
                emit_json({"recording": str(recording), "steps": steps, "view": view.url})
            else:
                click.echo(f"showed {steps} steps of {recording} on {view.url}")
        elif repair:
            report = repair_recording(recording)
            result = {"repaired": report.repaired, "messages": report.messages,
                      "kept": str(report.kept) if report.kept else None, "note": report.note,
                      "corrupted": report.corrupted, "dropped": report.dropped}
            if as_json:
                emit_json(result)
            else:
                click.echo(report.note)
        elif verify:
            from formic_record.replay import verify_recording

            report = verify_recording(recording)
            if as_json:
                emit_json(report.to_dict())
            else:
                click.echo(report.summary())
            if not report.ok:
                sys.exit(1)
        elif republish:
            from formic_ros.recorder import republish as play

            result = play(recording, rate=rate, domain_id=domain_id, topics=_split(topics), wait_s=wait, log=_log)
            if as_json:
                emit_json(result)
            else:
                click.echo(f"republished {result['messages']} messages on {len(result['topics'])} topics "
                           f"in {result['seconds']:.1f} s")
        else:
            rec = Recording(recording)
            if as_json:
                emit_json({"file": str(rec.mcap_path), "complete": rec.complete, "streamed": rec.streamed,
                       "problem": rec.problem, "run_info": rec.run_info,
                       "topics": {t: {"type": i.msgtype, "messages": i.count} for t, i in rec.topics.items()}})
                return
            click.echo(rec.describe())
            for topic, info in sorted(rec.topics.items()):
                click.echo(f"  {topic} [{info.msgtype}]: {info.count}")
            for key in ("seed", "config_digest", "policies", "checkpoint_id", "package_version"):
                if key in rec.run_info:
                    click.echo(f"  {key}: {rec.run_info[key]}")
    except (RecordingError, ValueError, OSError) as exc:
        raise click.ClickException(str(exc)) from exc


# ------------------------------------------------------------------------------- trainer
def training_config(preset: str, config_file: str | None, overrides: tuple[str, ...]):
    """``--preset`` (or a stored ``--train-config``) with ``--set`` overrides on top."""
    import dataclasses

    from formic_trainer.config import make_config, parse_overrides

    if config_file:
        from formic_trainer.config import load_train_config

        return dataclasses.replace(load_train_config(config_file), **parse_overrides(overrides))
    return make_config(preset, **parse_overrides(overrides))


@click.command("trainer")
@hosts_network_option
@click.option("--preset", default="cpu", show_default=True, type=click.Choice(["cpu", "paper"]))
@click.option("--run-dir", type=click.Path(file_okay=False), default="runs/formic-ros", show_default=True,
              help="Checkpoints (latest.pt) and TensorBoard logs; resumed unless --fresh.")
@click.option("--fresh", is_flag=True, help="Ignore an existing checkpoint in --run-dir.")
@click.option("--train-config", type=click.Path(exists=True, dir_okay=False),
              help="Start from this training configuration (a run directory's config.json) instead of --preset.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Override a training field.")
@click.option("--max-updates", type=int, help="Stop after this many updates (default: at Ctrl-C or SIGTERM).")
@click.option("--max-rollouts", type=int, help="Stop after this many rollouts, learned from or dropped.")
@click.option("--max-lag", default=4, show_default=True,
              help="Learn from rollouts at most this many weights versions old; drop older ones.")
@click.option("--namespace", default="/formic", show_default=True, help=NAMESPACE_HELP)
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object at the end.")
def trainer_command(preset, run_dir, fresh, train_config, overrides, max_updates, max_rollouts, max_lag, namespace,
                    domain_id, as_json) -> None:
    """The trainer node: learn from the hosts' rollouts, broadcast versioned weights."""
    from formic_ros.trainer_node import serve_trainer

    try:
        cfg = training_config(preset, train_config, overrides)
        result = serve_trainer(cfg, Path(run_dir), resume=not fresh, namespace=namespace, domain_id=domain_id,
                               max_updates=max_updates, max_rollouts=max_rollouts, max_lag=max_lag, log=_log)
    except (TypeError, ValueError) as exc:
        raise click.ClickException(str(exc)) from exc
    if as_json:
        emit_json(result)
    else:
        click.echo(f"trainer stopped at weights version {result['version']} ({result['updates']} updates here, "
                   f"{result['dropped']} rollouts dropped); checkpoint in {run_dir}/latest.pt")


def register(cli: click.Group) -> None:
    for command in (record_command, replay_command, trainer_command):
        cli.add_command(command)
