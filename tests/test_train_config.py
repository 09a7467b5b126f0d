"""A training setting out of its range is refused when the config is made, in one message naming
the setting as ``--set`` spells it: not a traceback from a world or torch, not a run that trains
on a nan loss (or the wrong way) without a word. Every shipped and committed config still loads:
tests/test_config_sentinels.py."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from formic_cli.main import cli
from formic_trainer.config import MIN_TRAINING_SIDE, make_config, parse_overrides
from formic_world import WorldConfig, generate_scenario
from formic_world.config import MIN_SIDE

TINY = ["--set", "teams=4", "--set", "world_sizes=16-16", "--set", "episode_steps=32", "--set", "rollout_steps=16",
        "--set", "threads=1"]
POLICIES = "formic, random, csaf, csaf11, csaf-ref, csaf11-ref, cardinality, planner"

REFUSED = [  # (--set, the message)
    ("seed=9223372036854775808", "seed 9223372036854775808 is over the limit of 9223372036854775807"),
    ("threads=100000", "threads 100000 is over the limit of 1024"),
    ("world_sizes=12-12", "world_sizes must be MIN-MAX side ranges within 16-2048, not 12-12"),
    ("world_sizes=15-20", "world_sizes must be MIN-MAX side ranges within 16-2048, not 15-20"),
    ("learning_agents=0", "learning_agents must be >= 1, or None or -1 for all, not 0"),
    ("value_coef=-1", "value_coef must be >= 0, not -1.0"),
    ("entropy_coef=-0.01", "entropy_coef must be >= 0, not -0.01"),
    ("valid_coef=-0.5", "valid_coef must be >= 0, not -0.5"),
    ("valid_join_coef=-1", "valid_join_coef must be >= 0, not -1.0"),
    ("imitation_coef=-1", "imitation_coef must be >= 0, not -1.0"),
    ("entropy_coef=nan", "entropy_coef must be a finite number, not nan"),
    ("clip=inf", "clip must be a finite number, not inf"),
    ("episode_steps=1000001", "episode_steps must be in [1, 1000000], not 1000001"),
    ("teams=16,65537", "teams must be team sizes of 1 to 65536, not 16,65537"),
    ("view_size=65", "view_size must be odd, 3 to 63, not 65"),
    ("imitate=foo", f"imitate must be one of {POLICIES}, or none for off, not 'foo'"),
    ("reward_overrides=deposit=nan", "reward_overrides: deposit needs a finite number, not 'nan'"),
    ("reward_overrides=blocked=-inf", "reward_overrides: blocked needs a finite number, not '-inf'"),
    ("preset=paper", "preset is chosen with --preset, not --set"),
]


def formic(*args: str):
    return CliRunner().invoke(cli, list(args))


@pytest.mark.parametrize("setting, expected", REFUSED)
def test_a_setting_out_of_range_is_refused_naming_it(setting, expected):
    with pytest.raises(ValueError) as error:
        make_config("cpu", **parse_overrides([setting]))
    assert str(error.value) == expected


@pytest.mark.parametrize("setting, expected", REFUSED)
def test_formic_train_refuses_it_in_one_line_before_training(tmp_path, setting, expected):
    result = formic("train", "--run-dir", str(tmp_path), "--episodes", "1", *TINY, "--set", setting)
    assert (result.exit_code, result.stderr, result.stdout) == (1, f"Error: {expected}\n", "")
    assert list(tmp_path.iterdir()) == []  # no checkpoint, log or config written


@pytest.mark.parametrize("command", [["train-ros", "--episodes", "1", "--run-dir", "unused"],
                                     ["actor", "--actor", "0", "--episodes", "1"]])
@pytest.mark.parametrize("setting, expected", [REFUSED[0], REFUSED[2], REFUSED[-3]])
def test_the_distributed_commands_refuse_it_the_same_way(command, setting, expected):
    result = formic(*command, *TINY, "--set", setting)
    assert (result.exit_code, result.stderr, result.stdout) == (1, f"Error: {expected}\n", "")


def test_the_smallest_sides_lay_out():
    """MIN_SIDE is the smallest side that lays out (12-14 never did: an IndexError or "could not lay
    out"); training draws even sides, so its ranges start at the even side above it."""
    assert MIN_TRAINING_SIDE == MIN_SIDE + 1 == 16
    for seed in range(5):
        for side in (MIN_SIDE, MIN_TRAINING_SIDE):
            generate_scenario(WorldConfig(height=side, width=side, n_agents=4, obstacle_density=0.05), seed)
    with pytest.raises(ValueError, match="world must be at least 15x15, got 14x14"):
        WorldConfig(height=14, width=14)


def test_the_edges_of_each_range_are_accepted():
    cfg = make_config("cpu", seed=2**63 - 1, threads=1024, world_sizes=((16, 16),), teams=(1,), learning_agents=1,
                      entropy_coef=0.0, value_coef=0.0, reward_overrides="deposit=0", imitate="csaf11")
    assert (cfg.seed, cfg.threads, cfg.world_sizes) == (2**63 - 1, 1024, ((16, 16),))
