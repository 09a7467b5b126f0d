"""``formic record``, ``formic replay`` and ``formic trainer``: recordings and the trainer node.
ROS and torch are imported inside the commands, so ``formic --help`` stays instant."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import click

from formic_ros.drivers.lag import DEFAULT_MAX_LAG  # no rclpy, no torch

from .options import (COUNT, NON_NEGATIVE, POSITIVE, PROCESS_DOMAIN_HELP, OutputFolder, domain_option, fresh_option,
                      hosts_network_option, json_option, live_view_port, open_live_view, preset_option, rclpy_refusal,
                      ros_options, ros_run_dir_option, train_config_option, training_config, view_options)
from .summary import click_errors, emit, emit_json

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
        each = f"{min(values)}-{max(values)}" if min(values) != max(values) else values[0]
        lines.append(f"{pattern} ({len(values)} topics): {each} each")
    return lines


def _log(text: str) -> None:
    click.echo(text, err=True)


def _split(values: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(t.strip() for v in values for t in v.split(",") if t.strip())


def _topic_names(ctx, param, values: tuple[str, ...]) -> tuple[str, ...]:
    """Absolute ROS topic names, checked before anything is recorded or played."""
    from rclpy.validate_full_topic_name import validate_full_topic_name

    for name in _split(values):
        try:
            validate_full_topic_name(name)
        except Exception as exc:  # rclpy's InvalidTopicNameException
            raise click.BadParameter(f"{name!r}: {rclpy_refusal(exc)}") from exc
    return values


@click.command("record")
@hosts_network_option
@click.option("--out", required=True, type=OutputFolder(),
              help="Recording directory to create (rosbag2 with MCAP storage).")
@click.option("--topics", multiple=True, metavar="TOPIC[,TOPIC]", callback=_topic_names,
              help="Absolute topic names to record (default: every topic in the namespace, and /clock).")
@ros_options(domain_help=PROCESS_DOMAIN_HELP)
@click.option("--model", type=click.Path(exists=True, dir_okay=False),
              help="Checkpoint the learned agents run: its id is stored with the recording.")
@click.option("--duration", type=POSITIVE, help="Stop after this many seconds (default: at Ctrl-C or SIGTERM).")
@click.option("--chunk-kb", type=COUNT, default=256, show_default=True,
              help="MCAP chunk size; a killed recorder loses at most its last chunk (or 0.5 s).")
@json_option(help="Print one JSON object at the end.")
def record_command(out, topics, namespace, domain_id, model, duration, chunk_kb, as_json) -> None:
    """Record ForMIC topics into a rosbag2 recording (MCAP) until interrupted."""
    from formic_agent.checkpoint import CheckpointError, checkpoint_id, read_checkpoint
    from formic_ros.recording.recorder import RecorderOptions, record

    if Path(out).exists():
        raise click.ClickException(f"{out} exists; a recording is never written over")
    if model:
        with click_errors(CheckpointError):  # the id stored names a model, not any file
            read_checkpoint(model)
    options = RecorderOptions(namespace=namespace, topics=_split(topics),
                              checkpoint_id=checkpoint_id(model) if model else "", chunk_bytes=chunk_kb * 1024)
    with click_errors(ValueError):
        result = record(out, options, domain_id=domain_id, duration_s=duration,
                        on_ready=lambda node: _log(f"recording to {out} (Ctrl-C to stop)"))
    if as_json:
        emit_json(result)
        return
    click.echo(f"wrote {result['recording']}: {result['messages']} messages on {len(result['topics'])} topics")
    for line in grouped_topic_lines(result["topics"]):
        click.echo(f"  {line}")
    for topic, why in result["skipped"].items():
        click.echo(f"  not recorded: {topic} ({why})")


@click.command("replay")
@click.argument("recording", type=click.Path(exists=True))
@click.option("--verify", is_flag=True, help="Re-simulate from the scenario and applied actions; every "
              "recorded state must match bit for bit (exit status 1 if not).")
@click.option("--republish", is_flag=True, help="Publish the recorded topics again on their recorded clock.")
@click.option("--repair", is_flag=True, help="Rebuild the index and metadata.yaml of a recording cut short "
              "(the original file is kept as <name>.mcap.truncated).")
@view_options()
@click.option("--rate", type=NON_NEGATIVE, default=1.0, show_default=True,
              help="--republish and --view speed factor (--view: of sim time; 0: as fast as possible).")
@click.option("--topics", multiple=True, metavar="TOPIC[,TOPIC]", callback=_topic_names,
              help="--republish only these topics.")
@click.option("--wait", type=NON_NEGATIVE, default=1.0, show_default=True,
              help="--republish starts once every topic has a subscriber, or after this many seconds.")
@domain_option(help=PROCESS_DOMAIN_HELP)
@json_option()
def replay_command(recording, verify, republish, repair, live_view, view_port, view_wait, rate, topics, wait,
                   domain_id, as_json) -> None:
    """Verify, republish, view or repair a recording (without a mode: describe it)."""
    from formic_record.reading import Recording, RecordingError, repair_recording

    if verify + republish + repair + live_view > 1:
        raise click.UsageError("choose one of --verify, --republish, --view, --repair")
    live_view_port(live_view, view_port, view_wait)
    with click_errors(RecordingError, ValueError, OSError):
        if live_view:
            from formic_record.replay import view_recording

            with open_live_view(view_port, wait=view_wait) as view:
                url = view.url  # the port served (with --view-port 0, the one chosen), while it is served
                steps = view_recording(recording, view, rate=rate)
            emit(as_json, {"recording": str(recording), "steps": steps, "view": url},
                 f"showed {steps} steps of {recording} on {url}")
        elif repair:
            report = repair_recording(recording)
            emit(as_json, {"repaired": report.repaired, "messages": report.messages,
                           "kept": str(report.kept) if report.kept else None, "note": report.note,
                           "corrupted": report.corrupted, "dropped": report.dropped}, report.note)
        elif verify:
            from formic_record.verify import verify_recording

            report = verify_recording(recording)
            emit(as_json, report.to_dict(), report.summary())
            if not report.ok:
                sys.exit(1)
        elif republish:
            from formic_ros.recording.recorder import republish as play

            result = play(recording, rate=rate, domain_id=domain_id, topics=_split(topics), wait_s=wait, log=_log)
            emit(as_json, result, f"republished {result['messages']} messages on "
                 f"{len(result['topics'])} topics in {result['seconds']:.1f} s")
        else:
            rec = Recording(recording)
            if as_json:
                topics = {t: {"type": i.msgtype, "messages": i.count} for t, i in rec.topics.items()}
                emit_json({"file": str(rec.mcap_path), "complete": rec.complete, "streamed": rec.streamed,
                           "problem": rec.problem, "run_info": rec.run_info, "topics": topics})
                return
            click.echo(rec.describe())
            for topic, info in sorted(rec.topics.items()):
                click.echo(f"  {topic} [{info.msgtype}]: {info.count}")
            for key in ("seed", "config_digest", "policies", "checkpoint_id", "package_version"):
                if key in rec.run_info:
                    click.echo(f"  {key}: {rec.run_info[key]}")


@click.command("trainer")
@hosts_network_option
@preset_option
@ros_run_dir_option
@fresh_option
@train_config_option
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Override a training field.")
@click.option("--max-updates", type=COUNT, help="Stop after this many updates (default: at Ctrl-C or SIGTERM).")
@click.option("--max-rollouts", type=COUNT, help="Stop after this many rollouts, learned from or dropped.")
@click.option("--max-lag", type=click.IntRange(min=0), default=DEFAULT_MAX_LAG, show_default=True,
              help="Learn from rollouts at most this many weights versions old; drop older ones.")
@click.option("--actors", type=click.IntRange(min=0), default=0,
              help="Wait for this many actors (`formic actor`, one per world) and update from all their rollouts.")
@click.option("--actor-deadline", "actor_deadline_s", type=POSITIVE, default=30.0, show_default=True,
              help="With --actors: seconds after an update's first rollout before it goes on without a silent actor.")
@click.option("--asynchronous", is_flag=True,
              help="With --actors: one update from each actor's rollout as it comes, up to --max-lag versions old "
                   "(the actors run with --switch-weights newest); changes learning.")
@ros_options(domain_help=PROCESS_DOMAIN_HELP)
@json_option(help="Print one JSON object at the end.")
def trainer_command(preset, run_dir, fresh, train_config, overrides, max_updates, max_rollouts, max_lag, namespace,
                    domain_id, as_json, actors, actor_deadline_s, asynchronous) -> None:
    """The trainer node: learn from the hosts' rollouts, broadcast versioned weights."""
    from formic_ros.drivers.trainer import serve_trainer

    with click_errors(TypeError, ValueError):
        if asynchronous and not actors:
            raise click.UsageError("--asynchronous goes with --actors K (a plain trainer learns from every rollout "
                                   "as it comes already)")
        cfg = training_config(preset, train_config, overrides)
        result = serve_trainer(cfg, Path(run_dir), resume=not fresh, namespace=namespace, domain_id=domain_id,
                               max_updates=max_updates, max_rollouts=max_rollouts, max_lag=max_lag, log=_log,
                               actors=actors, actor_deadline_s=actor_deadline_s, synchronous=not asynchronous)
    emit(as_json, result, f"trainer stopped at weights version {result['version']} ({result['updates']} "
         f"updates here, {result['dropped']} rollouts dropped); checkpoint in {run_dir}/latest.pt")


def register(cli: click.Group) -> None:
    for command in (record_command, replay_command, trainer_command):
        cli.add_command(command)
