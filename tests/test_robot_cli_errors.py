"""Bad input to the robot commands (``formic robot``, ``robots-sim``, ``scenarios starts`` and the
robot options of ``run`` and ``world``) is a usage error naming its option, raised while the command
line is parsed: before any ROS process starts, so no test here needs one. An id range too large to
build fails at once instead of hanging, and a topic template fails on the command line rather than
in a node's KeyError or rclpy's InvalidTopicName."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from formic_cli.main import cli
from formic_cli.robot_commands import robot
from formic_runtime.team import parse_ids

NOT_A_FIELD = "the only field is the agent id, {agent} (or {id})"
TOPIC_CHARACTERS = "topic name must not contain characters other than alphanumerics, '_', '~', '{', or '}'"

BAD_VALUES = [  # (command, what follows "Error: Invalid value for ")
    # id ranges: bounded before they are built; an empty list drives no robot
    (["robot", "--agent", "0-100000000", "--policy", "random"],
     "'--agent': agent range '0-100000000' is outside 0-65535"),
    (["robots-sim", "--robots", "0-100000000"], "'--robots': agent range '0-100000000' is outside 0-65535"),
    (["scenarios", "starts", "--robots", "0-100000000"], "'--robots': agent range '0-100000000' is outside 0-65535"),
    (["world", "--robots", "65536"], "'--robots': agent range '65536' is outside 0-65535"),
    (["robots-sim", "--robots", ""], "'--robots': no agent ids in ''"),
    (["robot", "--agent", " , "], "'--agent': no agent ids in ' , '"),
    (["robots-sim", "--robots", "-1"], "'--robots': bad agent range '-1'"),
    (["robots-sim", "--robots", "3-1"], "'--robots': bad agent range '3-1'"),
    # topic templates: the agent id is their only field, and what they make is a ROS topic name
    (["robots-sim", "--robots", "0", "--odom", "{x}"], f"'--odom': '{{x}}': {NOT_A_FIELD}"),
    (["robot", "--agent", "0", "--cmd-vel", "/r{agent[0]}"], f"'--cmd-vel': '/r{{agent[0]}}': {NOT_A_FIELD}"),
    (["robot", "--agent", "0", "--cmd-vel", "/r{agent.real}"], f"'--cmd-vel': '/r{{agent.real}}': {NOT_A_FIELD}"),
    (["robots-sim", "--robots", "0", "--odom", "/r{agent.x}"], f"'--odom': '/r{{agent.x}}': {NOT_A_FIELD}"),
    (["robots-sim", "--robots", "0", "--odom", "/r{agent:c}"], f"'--odom': '/r{{agent:c}}': {NOT_A_FIELD}"),
    (["robot", "--agent", "0", "--odom", "/r{id!r}"], f"'--odom': '/r{{id!r}}': {NOT_A_FIELD}"),
    (["robot", "--agent", "0", "--odom", "/r{agent}{"], f"'--odom': '/r{{agent}}{{': {NOT_A_FIELD}"),
    (["run", "--robots", "0", "--robot-odom", "/r{agent:03}"], f"'--robot-odom': '/r{{agent:03}}': {NOT_A_FIELD}"),
    (["robot", "--agent", "0", "--cmd-vel", "a b"], f"'--cmd-vel': 'a b': {TOPIC_CHARACTERS}"),
    (["robot", "--agent", "0", "--cmd-vel", ""], "'--cmd-vel': '': topic name must not be empty string"),
    (["robot", "--agent", "0", "--pose", "a b"], f"'--pose': 'a b': {TOPIC_CHARACTERS}"),
    (["robots-sim", "--robots", "0", "--cmd-vel", "a b"], f"'--cmd-vel': 'a b': {TOPIC_CHARACTERS}"),
    (["robots-sim", "--robots", "0", "--odom", "/r_{{x}}/odom"],
     "'--odom': '/r_{{x}}/odom': unknown substitution: {x}"),
    (["run", "--robots", "0", "--robot-cmd-vel", "/r_{{ns}}_{id}/x y"],
     f"'--robot-cmd-vel': '/r_{{{{ns}}}}_{{id}}/x y': {TOPIC_CHARACTERS}"),
    # cell sizes: positive and finite wherever they are given
    (["scenarios", "starts", "--cell-size", "nan"], "'--cell-size': nan is not a finite number"),
    (["world", "--robots", "0", "--cell-size", "0"], "'--cell-size': 0.0 is not in the range x>0."),
    (["run", "--robots", "0", "--robots-sim", "--cell-size", "0"], "'--cell-size': 0.0 is not in the range x>0."),
    (["robots-sim", "--robots", "0", "--cell-size", "inf"], "'--cell-size': inf is not a finite number"),
    # speeds, accelerations, noise and stalls: named as the options, not as the settings' fields
    (["robot", "--agent", "0", "--max-turn", "-1"], "'--max-turn': -1.0 is not in the range x>0."),
    (["robot", "--agent", "0", "--stall-s", "0"], "'--stall-s': 0.0 is not in the range x>0."),
    (["robots-sim", "--robots", "0", "--max-speed", "0"], "'--max-speed': 0.0 is not in the range x>0."),
    (["robots-sim", "--robots", "0", "--accel", "0"], "'--accel': 0.0 is not in the range x>0."),
    (["robots-sim", "--robots", "0", "--noise", "-1"], "'--noise': -1.0 is not in the range x>=0."),
    (["robots-sim", "--robots", "0", "--stall-rate", "-1"], "'--stall-rate': -1.0 is not in the range x>=0."),
    (["robots-sim", "--robots", "0", "--stall-s", "-1"], "'--stall-s': -1.0 is not in the range x>0."),
    (["robots-sim", "--robots", "0", "--max-speed", "nan"], "'--max-speed': nan is not a finite number"),
    (["run", "--robots", "0", "--robot-max-speed", "0"], "'--robot-max-speed': 0.0 is not in the range x>0."),
    (["run", "--robots", "0", "--robot-max-turn", "inf"], "'--robot-max-turn': inf is not a finite number"),
    (["run", "--robots", "0", "--robot-stall-s", "-1"], "'--robot-stall-s': -1.0 is not in the range x>0."),
    (["world", "--robots", "0", "--robot-tolerance", "0"], "'--robot-tolerance': 0.0 is not in the range x>0."),
    (["world", "--robots", "0", "--robot-cell-s", "-1"], "'--robot-cell-s': -1.0 is not in the range x>0."),
    (["robots-sim", "--robots", "0", "--seed", "-1"], "'--seed': -1 is not in the range x>=0."),
    (["robots-sim", "--robots", "0", "--origin-x", "nan"], "'--origin-x': nan is not a finite number"),
    (["robot", "--agent", "0", "--odom-origin", "1,nan,0"],
     "'--odom-origin': odometry origin '1,nan,0': use map, start or X,Y,YAW (finite metres, radians)"),
    (["robot", "--agent", "0", "--odom-origin", "1,2"],
     "'--odom-origin': odometry origin '1,2': use map, start or X,Y,YAW (finite metres, radians)"),
]


@pytest.mark.parametrize("command, message", BAD_VALUES, ids=lambda v: " ".join(v) if isinstance(v, list) else "")
def test_a_bad_robot_option_is_a_usage_error_naming_it(command, message):
    result = CliRunner().invoke(cli, command)
    assert (result.exit_code, result.stdout) == (2, ""), result.output
    assert result.stderr.endswith(f"Error: Invalid value for {message}\n")
    assert "Traceback" not in result.stderr


def test_a_huge_id_range_is_refused_without_being_built():
    """Refused from its bounds (built, 0-100000000 would take gigabytes and minutes)."""
    with pytest.raises(ValueError, match=r"agent range '0-100000000' is outside 0-65535"):
        parse_ids("0-100000000")
    with pytest.raises(ValueError, match=r"agent range '2-9' is outside 0-3"):
        parse_ids("0,2-9", n_agents=4)


def test_valid_ids_parse_as_before():
    assert parse_ids("0-3,8+10-11") == [0, 1, 2, 3, 8, 10, 11]
    assert parse_ids(" 5 , 3-4,5") == [3, 4, 5]
    assert parse_ids("65535") == [65535]
    assert len(parse_ids("0-65535")) == 65536


@pytest.mark.parametrize("template, topic", [("/r{id}/cmd_vel", "/r{agent}/cmd_vel"),
                                             ("r_{agent}_{{node}}", "r_{agent}_{{node}}"),
                                             ("/cmd_vel", "/cmd_vel")])
def test_formic_robot_takes_a_template_with_either_field_name(template, topic):
    """``{id}`` (as ``formic run`` writes it) reaches the bridge as ``{agent}``, the field it fills."""
    with robot.make_context("robot", ["--agent", "0", "--cmd-vel", template]) as ctx:
        assert ctx.params["cmd_vel"] == topic
