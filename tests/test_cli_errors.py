"""Bad input to the ``formic`` command ends in one line on stderr and a non-zero status, never a
traceback: too many agents, corrupt scenario files, missing or foreign model files, a resume
with other settings, a non-positive episode length, a bad ``--set``, and files or worlds over the
limits of formic_world.limits (refused before anything is allocated). Also: a stored scenario set has the
episodes ``formic eval`` runs, and Ctrl-C of a node logs no FATAL error."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from formic_agent.checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION
from formic_agent.inputs import NETWORK_PRESETS
from formic_cli.main import cli
from formic_eval.paper import PAPER_STEPS
from formic_world import Scenario, WorldConfig, generate_scenario
from formic_world.limits import MAX_CHECKPOINT_BYTES, MAX_SCENARIO_BYTES

TINY_WORLD = ["--size", "16", "--agents", "4", "--steps", "5"]
TINY_TRAINING = ["--set", "teams=4", "--set", "world_sizes=16-16", "--set", "episode_steps=32",
                 "--set", "rollout_steps=16", "--set", "threads=1"]


def formic(*args: str):
    return CliRunner().invoke(cli, list(args))


def assert_one_line_error(result, expected: str, status: int = 1) -> None:
    assert (result.exit_code, result.stderr, result.stdout) == (status, f"Error: {expected}\n", "")


def formic_process(*args: str, ros: bool = False) -> subprocess.CompletedProcess:
    """The real command in a process of its own (ROS commands: on a test domain)."""
    env = None
    if ros:
        pytest.importorskip("rclpy")
        from ros_helpers import fresh_domain_id, ros_test_environment

        env = ros_test_environment(fresh_domain_id())
    return subprocess.run([sys.executable, "-m", "formic_cli.main", *args], capture_output=True, text=True,
                          env=env, timeout=120)


def test_more_agents_than_fit_is_one_line():
    result = formic_process("sim", "--agents", "2000", "--size", "16")
    assert (result.returncode, result.stderr) == (
        1, "Error: no room for 2000 agents: a 16x16 world has 172 free cells to start on\n")


def _scenario_text(**changes) -> str:
    data = generate_scenario(WorldConfig(height=16, width=16, n_agents=4, episode_steps=5), 0).to_dict()
    data["config"].update(changes.pop("config", {}))
    data.update(changes)
    return json.dumps(data)


CORRUPT_SCENARIOS = {  # file content -> the reason after "PATH: "
    "truncated": ('{"format": "formic-scenario", "version": 2, "seed": ',
                  "scenario is not valid JSON: Expecting value: line 1 column 53 (char 52)"),
    "binary": (bytes(range(256)), "not a text file"),
    "no agents": (json.dumps({k: v for k, v in json.loads(_scenario_text()).items() if k != "agents"}),
                  "malformed scenario: no 'agents' field"),
    "seed not a number": (_scenario_text(seed="x"), "malformed scenario: invalid literal for int() with base 10: 'x'"),
    "no steps": (_scenario_text(config={"episode_steps": 0}), "malformed scenario: episode_steps must be >= 1, got 0"),
    "a list": ("[1, 2]", "scenario must be a JSON object"),
}


@pytest.mark.parametrize("kind", CORRUPT_SCENARIOS)
@pytest.mark.parametrize("command", [["sim"], ["scenarios", "show"], ["render"]])
def test_a_corrupt_scenario_file_is_one_line(tmp_path, kind, command):
    content, reason = CORRUPT_SCENARIOS[kind]
    path = tmp_path / "bad.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    args = [*command, "--scenario", str(path), "--out", str(tmp_path)] if command == ["sim"] else [*command, str(path)]
    assert_one_line_error(formic(*args), f"{path}: {reason}")


def test_a_scenario_over_the_world_limits_is_refused_at_once(tmp_path):
    path = tmp_path / "tall.json"
    path.write_text(_scenario_text(config={"height": 1_000_000}))
    start = time.monotonic()
    result = formic("sim", "--scenario", str(path), "--out", str(tmp_path))
    assert time.monotonic() - start < 1.0
    assert_one_line_error(result, f"{path}: malformed scenario: height 1000000 is over the limit of 2048")
    process = formic_process("sim", "--scenario", str(path), "--out", str(tmp_path))
    assert (process.returncode, process.stderr, process.stdout) == (1, f"Error: {path}: malformed scenario: "
                                                                       "height 1000000 is over the limit of 2048\n", "")


def test_a_scenario_file_over_the_size_limit_is_refused_unread(tmp_path):
    path = tmp_path / "huge.json"
    with open(path, "wb") as handle:  # sparse: no disk is written
        handle.truncate(MAX_SCENARIO_BYTES + 1)
    result = formic("sim", "--scenario", str(path), "--out", str(tmp_path))
    assert_one_line_error(result, f"{path}: 67,108,865 bytes is over the limit of 67,108,864 for a scenario file")


def test_eval_names_the_corrupt_file_of_a_scenario_directory(tmp_path):
    (tmp_path / "set").mkdir()
    (tmp_path / "set" / "bad.json").write_bytes(bytes(range(256)))
    result = formic("eval", "--algorithms", "random", "--scenarios", str(tmp_path / "set"), "--out", str(tmp_path))
    assert_one_line_error(result, f"scenarios: {tmp_path / 'set' / 'bad.json'}: not a text file")


def test_world_and_run_report_a_corrupt_scenario_file_in_one_line(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text("[1, 2]")
    for command in ("world", "run"):
        result = formic_process(command, "--scenario", str(path), ros=True)
        assert (result.returncode, result.stderr) == (1, f"Error: {path}: scenario must be a JSON object\n"), command


def _foreign_files(directory: Path) -> dict[str, tuple[Path, str]]:
    """Files that are no ForMIC checkpoint -> (path, the reason after "PATH: ")."""
    unreadable = "not a readable ForMIC checkpoint"
    files = {"garbage": bytes(range(7, 256)), "empty": b"", "text": b"hello, world\n"}
    paths = {}
    for name, content in files.items():
        paths[name] = directory / f"{name}.pt"
        paths[name].write_bytes(content)
    paths["tensor"] = directory / "tensor.pt"
    torch.save(torch.zeros(3), paths["tensor"])
    paths["module"] = directory / "module.pt"  # torch's own refusal advises weights_only=False
    torch.save({"layer": torch.nn.Linear(2, 2)}, paths["module"])
    paths["code"] = directory / "code.pt"
    paths["code"].write_bytes(pickle.dumps(subprocess.Popen))
    paths["zip"] = directory / "archive.pt"
    with zipfile.ZipFile(paths["zip"], "w") as archive:
        archive.writestr("notes.txt", "hello")
    paths["truncated"] = directory / "truncated.pt"
    paths["truncated"].write_bytes((Path(__file__).parents[1] / "models" / "formic_paper.pt").read_bytes()[:3000])
    plain = f"{unreadable} (not a torch file of tensors and plain data)"
    no_zip = "not a ForMIC checkpoint (torch.save writes a zip archive; this is something else)"
    return {
        "garbage": (paths["garbage"], no_zip),
        "empty": (paths["empty"], "not a ForMIC checkpoint (the file is empty)"),
        "text": (paths["text"], no_zip),  # torch itself would fail with "KeyError: 104"
        "tensor": (paths["tensor"], "not a ForMIC checkpoint"),
        "module": (paths["module"], plain),
        "code": (paths["code"], no_zip),
        "zip": (paths["zip"], f"{unreadable} (RuntimeError: [enforce fail at inline_container.cc:180] . file in "
                              "archive is not in a subdirectory: notes.txt)"),
        "truncated": (paths["truncated"], f"{unreadable} (RuntimeError: PytorchStreamReader failed reading zip "
                                          "archive: failed finding central directory)"),
    }


@pytest.mark.parametrize("kind", ["garbage", "empty", "text", "tensor", "module", "code", "zip", "truncated"])
def test_a_file_that_is_no_checkpoint_is_one_line_without_unsafe_advice(tmp_path, kind):
    path, reason = _foreign_files(tmp_path)[kind]
    result = formic("sim", *TINY_WORLD, "--model", str(path), "--out", str(tmp_path))
    assert_one_line_error(result, f"{path}: {reason}")
    assert "weights_only" not in result.output


def test_a_text_file_named_pt_is_refused_before_torch_reads_it(tmp_path, monkeypatch):
    path = tmp_path / "x.pt"
    path.write_text("e" * 40)  # torch would read it as a legacy pickle and fail with "KeyError: 101"
    monkeypatch.setattr(torch, "load", None)  # a call would fail with a TypeError instead
    result = formic("sim", *TINY_WORLD, "--model", str(path), "--out", str(tmp_path))
    assert_one_line_error(result, f"{path}: not a ForMIC checkpoint (torch.save writes a zip archive; this is "
                                  "something else)")


def test_a_model_file_over_the_size_limit_is_refused_unread(tmp_path):
    path = tmp_path / "huge.pt"
    with open(path, "wb") as handle:  # sparse: no disk is written
        handle.truncate(MAX_CHECKPOINT_BYTES + 1)
    result = formic("sim", *TINY_WORLD, "--model", str(path), "--out", str(tmp_path))
    assert_one_line_error(result, f"{path}: 536,870,913 bytes is over the limit of 536,870,912 for a model file")


@pytest.mark.parametrize("field", ["conv1", "conv2", "fc", "rnn", "channels"])
def test_a_checkpoint_asking_for_a_network_over_the_width_limit_is_refused_before_allocation(tmp_path, field):
    path = tmp_path / "wide.pt"
    network = {**NETWORK_PRESETS["cpu"].to_dict(), field: 1_000_000}  # allocated, fc alone would take 4 TB
    torch.save({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "network": network, "state_dict": {}},
               path)
    result = formic("sim", *TINY_WORLD, "--model", str(path), "--out", str(tmp_path))
    assert_one_line_error(result, f"{path}: network {field} 1000000 is over the limit of 4096")


def test_eval_and_an_agent_host_report_a_foreign_model_the_same_way(tmp_path):
    path, reason = _foreign_files(tmp_path)["module"]
    result = formic("eval", "--algorithms", "formic", "--model", str(path), "--sizes", "16", "--teams", "4",
                    "--scenarios", "1", "--steps", "5", "--out", str(tmp_path / "eval"))
    assert_one_line_error(result, f"{path}: {reason}")
    host = formic_process("agents", "--ids", "0", "--model", str(path), ros=True)
    assert (host.returncode, host.stderr) == (1, f"Error: {path}: {reason}\n")


def test_a_missing_model_is_one_line_for_sim_eval_and_run(tmp_path):
    missing = tmp_path / "none.pt"
    expected = f"no model at {missing}: train one with `formic train` or pass --model"
    assert_one_line_error(formic("sim", *TINY_WORLD, "--model", str(missing), "--out", str(tmp_path)), expected)
    assert_one_line_error(formic("eval", "--algorithms", "formic", "--model", str(missing), "--scenarios", "1",
                                 "--out", str(tmp_path)), expected)
    run = formic_process("run", *TINY_WORLD, "--model", str(missing), ros=True)  # refused before any process starts
    assert (run.returncode, run.stderr) == (1, f"Error: {expected}\n")


def test_resuming_training_with_other_settings_is_one_line(tmp_path):
    run_dir = tmp_path / "run"
    first = formic("train", "--run-dir", str(run_dir), "--episodes", "1", *TINY_TRAINING)
    assert first.exit_code == 0, first.output
    again = formic("train", "--run-dir", str(run_dir), "--episodes", "1", *TINY_TRAINING, "--set", "lr=0.001")
    assert_one_line_error(again, f"{run_dir / 'latest.pt'} was trained with different settings (lr); use the same "
                                 "settings, a new --run-dir, or --fresh")


@pytest.mark.parametrize("setting, expected", [
    ("lr=abc", "lr expects a number, got 'abc'"),
    ("seed=1.5", "seed expects an integer, got '1.5'"),
    ("pheromones=maybe", "pheromones expects true/false, got 'maybe'"),
    ("teams=8,x", "teams expects team sizes separated by commas (16,32), got '8,x'"),
    ("world_sizes=40:96", "world_sizes expects MIN-MAX side ranges, one per team (40-96,64-128), got '40:96'"),
    ("obstacle_range=0,1", "obstacle_range cannot be set from the command line"),
    ("optimizer=sgd", "optimizer must be one of 'nadam', 'adam', not 'sgd'"),
    ("lrr=0.1", "'lrr' is not a TrainConfig field (did you mean lr?): the settings are listed in docs/training.md"),
    ("lr", "--set 'lr': expected FIELD=VALUE with a TrainConfig field"),
    ("teams=16,0", "teams must be team sizes of 1 to 65536, not 16,0"),
    ("world_sizes=5-16", "world_sizes must be MIN-MAX side ranges within 16-2048, not 5-16"),
    ("view_size=4", "view_size must be odd, 3 to 63, not 4"),
    ("seed=-1", "seed must be >= 0, not -1"),
    ("rollout_steps=0", "rollout_steps must be >= 1, not 0"),
    ("gamma=nan", "gamma must be a finite number, not nan"),
    ("gae_lambda=1.5", "gae_lambda must be in [0, 1], not 1.5"),
    ("lr=0", "lr must be > 0, not 0.0"),
])
def test_every_set_error_names_its_key(tmp_path, setting, expected):
    """Refused before any world is built or update made (a nan gamma would train on as a nan loss)."""
    assert_one_line_error(formic("train", "--run-dir", str(tmp_path), "--set", setting), expected)


@pytest.mark.parametrize("command", [["train-ros", "--episodes", "1", "--run-dir", "unused"],
                                     ["trainer", "--run-dir", "unused"], ["actor", "--actor", "0", "--episodes", "1"]])
def test_the_distributed_commands_refuse_a_bad_setting_the_same_way(command):
    assert_one_line_error(formic(*command, "--set", "teams=0"), "teams must be team sizes of 1 to 65536, not 0")


def test_exporting_from_a_run_directory_without_a_checkpoint_is_one_line(tmp_path):
    result = formic("train", "--run-dir", str(tmp_path), "--episodes", "0", "--export", str(tmp_path / "m.pt"))
    assert_one_line_error(result, f"{tmp_path / 'latest.pt'}: cannot read (No such file or directory)")


@pytest.mark.parametrize("command", [["sim"], ["scenarios", "generate", "--out", "unused"], ["bench", "world"]])
@pytest.mark.parametrize("steps", ["0", "-3"])
def test_a_non_positive_episode_length_is_a_usage_error(command, steps):
    result = formic(*command, "--steps", steps)
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.endswith(f"Error: Invalid value for '--steps': {steps} is not in the range 1<=x<=1000000.\n")


OUT_OF_BOUNDS = [  # (command, the message after "Error: Invalid value for ")
    (["sim", "--size", "100000"], "'--size': 100000 is not in the range 15<=x<=2048."),
    (["sim", "--size", "5"], "'--size': 5 is not in the range 15<=x<=2048."),
    (["sim", "--agents", "70000"], "'--agents': 70000 is not in the range 1<=x<=65536."),
    (["sim", "--view-size", "4"], "'--view-size': 4 is even: the window is centred on its agent (5, 11, 21)"),
    (["sim", "--view-size", "99"], "'--view-size': 99 is not in the range 3<=x<=63."),
    (["sim", "--obstacles", "0.5"], "'--obstacles': 0.5 is not in the range 0<=x<0.5."),
    (["scenarios", "generate", "--size", "9999", "--out", "unused"], "'--size': 9999 is not in the range 15<=x<=2048."),
    (["eval", "--sizes", "128,100000"], "'--sizes': 100000 is not in the range 15<=x<=2048."),
    (["eval", "--teams", "16,0"], "'--teams': 0 is not in the range 1<=x<=65536."),
    (["eval", "--obstacles", "0,0.6"], "'--obstacles': 0.6 is not in the range 0<=x<0.5."),
    (["bench", "world", "--teams", "16,x"], "'--teams': 'x' is not a valid integer range."),
    (["bench", "world", "--size", "4096"], "'--size': 4096 is not in the range 15<=x<=2048."),
    (["bench", "decide", "--teams", "0"], "'--teams': 0 is not in the range 1<=x<=65536."),
    (["bench", "decide", "--threads", "-1"], "'--threads': -1 is not in the range x>=0."),
    (["bench", "policy", "--network", "huge"],
     "'--network': 'huge' is not one of 'cpu', 'cpu-feedback', 'cpu-nest', 'paper'."),
    (["bench", "policy", "--batch", "0"], "'--batch': 0 is not in the range x>=1."),
    (["bench", "ros", "--agents", "16,,abc"], "'--agents': 'abc' is not a valid integer range."),
    (["bench", "ros", "--transports", "batched,udp"],
     "'--transports': unknown udp; choose from per-agent, batched"),
    (["bench", "ros", "--steps", "1"], "'--steps': 1 is not in the range 2<=x<=1000000."),
]


BAD_VALUES = [  # (command, the message after "Error: Invalid value for "): refused before anything starts
    (["sim", "--seed", "-1"], "'--seed': -1 is not in the range x>=0."),
    (["sim", "--view", "--view-port", "70000"], "'--view-port': 70000 is not in the range 0<=x<=65535."),
    (["sim", "--model", ""], "'--model': an empty name: give a file, or leave the option out"),
    (["sim", "--steps", "2", "--wipeouts", "3"], "'--wipeouts': wipeouts do not fit in the episode"),
    (["scenarios", "generate", "--out", "unused", "--count", "0"], "'--count': 0 is not in the range x>=1."),
    (["record", "--out", ""], "'--out': an empty name: give a folder"),
    (["record", "--out", "unused", "--topics", "/formic/state,state"],
     "'--topics': 'state': topic name must be absolute, it must lead with a '/'"),
    (["record", "--out", "unused", "--duration", "-1"], "'--duration': -1.0 is not in the range x>0."),
    (["replay", ".", "--rate", "nan"], "'--rate': nan is not a finite number"),
    (["run", "--timeout", "0"], "'--timeout': 0.0 is not in the range x>0."),
    (["run", "--agents", "4", "--size", "16", "--hosts", "5"], "'--hosts': 5 hosts for 4 agents: at most one an agent"),
    (["world", "--namespace", "a b"],
     "'--namespace': namespace must not contain characters other than alphanumerics, '_', or '/'"),
    (["world", "--domain-id", "-1"], "'--domain-id': -1 is not in the range 0<=x<=232."),
    (["world", "--dt", "0"], "'--dt': 0.0 is not in the range x>0."),
    (["world", "--origin-x", "inf"], "'--origin-x': inf is not a finite number"),
    (["agents", "--ids", "abc"], "'--ids': bad agent range 'abc'"),
    (["agents", "--ids", "0-1", "--name", "bad name"],
     "'--name': node name must not contain characters other than alphanumerics or '_'"),
    (["trainer", "--max-updates", "-1"], "'--max-updates': -1 is not in the range x>=1."),
    (["train-ros", "--episodes", "0"], "'--episodes': 0 is not in the range x>=1."),
    (["render", ".", "--out", "run.txt"], "'--out': 'run.txt': a recording renders to .png, .gif, .mp4"),
    (["render", ".", "--fps", "0"], "'--fps': 0 is not in the range 1<=x<=240."),
    (["eval", "--env", ""], "'--env': empty list"),
    (["agents", "--ids", "0-100000000"], "'--ids': agent range '0-100000000' is outside 0-65535"),
    (["run", "--external", "0-100000000"], "'--external': agent range '0-100000000' is outside 0-65535"),
    (["robot", "--agent", ""], "'--agent': no agent ids in ''"),  # more robot options: test_robot_cli_errors.py
]


@pytest.mark.parametrize("command, message", BAD_VALUES, ids=lambda v: " ".join(v) if isinstance(v, list) else "")
def test_a_bad_value_is_a_usage_error_naming_its_option(command, message):
    result = formic(*command)
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.endswith(f"Error: Invalid value for {message}\n")


@pytest.mark.parametrize("command", [["sim", "--out"], ["scenarios", "generate", "--out"], ["eval", "--out"],
                                     ["record", "--out"], ["run", "--log-dir"], ["run", "--record"],
                                     ["train", "--run-dir"], ["trainer", "--run-dir"]])
def test_an_output_folder_under_a_file_is_refused_before_the_work(tmp_path, command):
    (tmp_path / "file").write_text("")
    result = formic(*command, str(tmp_path / "file" / "out"))
    assert result.exit_code == 2 and result.stderr.endswith(
        f"Error: Invalid value for '{command[-1]}': '{tmp_path / 'file' / 'out'}' cannot be a folder: "
        f"{tmp_path / 'file'} is a file\n")


def test_files_that_are_not_what_a_command_reads_are_one_line(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(bytes(range(64)))
    assert_one_line_error(formic("replay", str(junk)),
                          f"{junk}: not an MCAP recording (its first bytes are not MCAP's)")
    assert_one_line_error(formic("render", str(junk), "--out", str(tmp_path / "run.gif")),
                          f"{junk}: not an MCAP recording (its first bytes are not MCAP's)")
    model = tmp_path / "model.pt"
    model.write_bytes(bytes(range(64)))
    assert_one_line_error(formic("record", "--out", str(tmp_path / "rec"), "--model", str(model)),
                          f"{model}: not a ForMIC checkpoint (torch.save writes a zip archive; this is something else)")
    config = tmp_path / "config.json"
    config.write_text("{")
    assert_one_line_error(formic("trainer", "--train-config", str(config)), f"{config}: not a training configuration: "
                          "Expecting property name enclosed in double quotes: line 1 column 2 (char 1)")
    none = tmp_path / "none"
    assert_one_line_error(formic("eval", "--report", "--out", str(none)),
                          f"{none}: no episodes to report (formic eval --out {none} plays them)")


def test_a_frame_too_large_to_draw_is_refused_before_it_is_allocated(tmp_path):
    path = tmp_path / "s.json"
    generate_scenario(WorldConfig(height=2048, width=2048, n_agents=4, episode_steps=5), 0).save(path)
    assert_one_line_error(formic("render", str(path), "--scale", "9", "--out", str(tmp_path / "s.png")),
                          "a 2048x2048 world at scale 9 is no frame: the scale goes from 1 to 8 "
                          "(16384 pixels a side at most)")


@pytest.mark.parametrize("command, message", OUT_OF_BOUNDS, ids=lambda v: " ".join(v) if isinstance(v, list) else "")
def test_a_value_out_of_the_worlds_bounds_is_a_usage_error_naming_its_option(command, message):
    """Before anything runs (no world, no network, no ROS process): the option the user typed,
    not the configuration field behind it."""
    result = formic(*command)
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.endswith(f"Error: Invalid value for {message}\n")


def test_stored_scenario_sets_have_the_episodes_eval_runs(tmp_path):
    result = formic("scenarios", "generate", "--size", "16", "--agents", "4", "--count", "1", "--out", str(tmp_path))
    assert result.exit_code == 0, result.output
    (path,) = tmp_path.glob("*.json")
    assert path.name == f"s16_n4_o0_infinite_w0_t{PAPER_STEPS}_seed0.json" and PAPER_STEPS == 1024
    assert Scenario.load(path).config.episode_steps == PAPER_STEPS
    help_text = " ".join(formic("scenarios", "generate", "--help").output.split())
    assert "the paper's test episodes, as `formic eval` runs them" in help_text
    assert "[default: 1024; 1<=x<=1000000]" in help_text


INTERRUPTED_IN_A_TIMER = """
import os, signal, sys, time
import rclpy
from formic_ros.env import ros_session

with ros_session() as executor:
    node = rclpy.create_node("probe", namespace="/formic")
    executor.add_node(node)

    def tick():
        os.kill(os.getpid(), getattr(signal, sys.argv[1]))
        time.sleep(0.05)  # the signal's handler runs here, inside the callback

    node.create_timer(0.01, tick)
    try:
        for _ in range(50):
            executor.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        print("interrupted")
        sys.exit(130)
"""


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_signal_during_a_timer_callback_stops_the_node_quietly(signal_name):
    """The executor would log an interrupt raised inside a callback as a FATAL error."""
    pytest.importorskip("rclpy")
    from ros_helpers import fresh_domain_id, ros_test_environment

    result = subprocess.run([sys.executable, "-c", INTERRUPTED_IN_A_TIMER, signal_name], capture_output=True,
                            text=True, env=ros_test_environment(fresh_domain_id()), timeout=60)
    assert (result.returncode, result.stdout, result.stderr) == (130, "interrupted\n", "")


@pytest.mark.parametrize("command", [["sim"], ["run"], ["world"]])
def test_view_wait_without_the_view_is_a_usage_error(command):
    """--view-wait waits for a viewer of --view: alone it would silently wait for nothing."""
    result = formic(*command, *TINY_WORLD, "--view-wait")
    assert result.exit_code == 2 and "--view-wait waits for a viewer of the live view: add --view" in result.output


def test_robot_options_of_formic_run_are_checked_before_any_process_starts():
    usage = formic("run", *TINY_WORLD, "--robots", "2", "--robot-odom-origin", "east")
    assert usage.exit_code == 2 and usage.stderr.splitlines()[-1] == (
        "Error: Invalid value for '--robot-odom-origin': odometry origin 'east': use map, start or X,Y,YAW "
        "(finite metres, radians)")
    assert_one_line_error(formic("run", *TINY_WORLD, "--robots", "1", "--robots-sim", "--robot-odom-origin", "start"),
                          "--robot-odom-origin is for real robots: the simulated robots' odometry is in the map frame")
    usage = formic("run", *TINY_WORLD, "--robots", "1", "--robot-cmd-vel", "/r{agent_id}/cmd_vel")
    assert usage.exit_code == 2 and usage.stderr.splitlines()[-1] == (
        "Error: Invalid value for '--robot-cmd-vel': '/r{agent_id}/cmd_vel': the only field is the agent id, "
        "{agent} (or {id})")


def test_scenarios_starts_prints_each_robots_start_cell_and_its_centre():
    result = formic("scenarios", "starts", "--agents", "8", "--size", "24", "--seed", "0", "--robots", "3,5",
                    "--cell-size", "0.5")
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines() == [
        "seed 0, 24x24, 0.5 m cells; x, y: the cell's centre in the map frame (m), facing east (yaw 0)",
        "agent   3: cell (13, 12) at x 6.250, y 5.250",
        "agent   5: cell (10, 13) at x 6.750, y 6.750",
    ]
    scenario = generate_scenario(WorldConfig(height=24, width=24, n_agents=8, episode_steps=512), 0)
    starts = json.loads(formic("scenarios", "starts", "--agents", "8", "--size", "24", "--seed", "0",
                               "--json").stdout)["starts"]
    assert [(s["row"], s["col"]) for s in starts] == [(int(a.row), int(a.col)) for a in scenario.agents]
    assert_one_line_error(formic("scenarios", "starts", "--agents", "8", "--robots", "9"),
                          "--robots [9]: not agents of this team of 8")


def test_a_timeline_goes_into_a_fresh_folder_and_its_report_names_what_is_missing(tmp_path, monkeypatch):
    """--timeline would mix two runs' marks in one folder; the report says what a folder lacks."""
    monkeypatch.delenv("FORMIC_TIMELINE", raising=False)
    (tmp_path / "world-1.csv").write_text("event,step,ns\n")
    usage = formic("run", *TINY_WORLD, "--timeline", str(tmp_path))
    assert usage.exit_code == 2 and usage.stderr.splitlines()[-1] == (
        f"Error: Invalid value for '--timeline': {tmp_path} already holds a run's timeline: "
        "give each run a fresh folder")
    planner = formic("run", *TINY_WORLD, "--policy", "planner", "--timeline", str(tmp_path / "fresh"))
    assert planner.exit_code == 2 and planner.stderr.splitlines()[-1] == (
        "Error: --timeline times agent hosts; the centralized planner runs without one")
    assert_one_line_error(formic("timeline", str(tmp_path)),
                          f"{tmp_path} holds 1 world and 0 host timelines: it needs one world's and its hosts' "
                          "(run `formic run --timeline DIR` with a fresh DIR)")
