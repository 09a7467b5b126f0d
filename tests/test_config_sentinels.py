"""Settings that can be off are None when off, and every older way of saying so still works:
``--set``, a recipe's TOML (which has no None), config.json files and checkpoints written before,
the identities of the shipped recipes and the claims of the committed runs."""

import dataclasses
import hashlib
import json
import shutil
import tomllib
from pathlib import Path

import pytest

from formic_agent.checkpoint import CheckpointError, read_checkpoint
from formic_trainer.config import OFF_SPELLINGS, load_train_config, make_config, off_as_none, parse_overrides
from formic_trainer.learner import Learner
from formic_trainer.recipes.definition import stage_config
from formic_trainer.recipes.files import SHIPPED, held_identity, load_recipe
from formic_trainer.recipes.parse import parse_recipe

ROOT = Path(__file__).resolve().parents[1]
TRAINING = ROOT / "models" / "training"

# each shipped recipe's identities (every switch, at scales 1, 0.5 and 0.25), as computed before these
# settings took None for off (paper-v5 and paper-v6, written after, as first computed): a run directory resumes
# only under the identity its claim holds
SHIPPED_IDENTITIES = {"paper": "a68ab20c7aa1cf40", "paper-v2": "0fb550916b507096", "paper-v3": "bbc98de8088e6e9f",
                      "paper-v4": "34efba19cbdca2f4", "paper-v5": "0b1ff86887a5c889",
                      "paper-v6": "4dc79fdf5cf986c4", "smoke": "d94b97bcdeafe27e"}


def digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def test_a_setting_that_is_off_is_none_and_its_old_spelling_reads_as_none():
    assert OFF_SPELLINGS == {"learning_agents": -1, "clip": 0.0, "target_kl": 0.0, "anneal_hold": 0.0,
                             "init_weights": "", "weight_average": 0.0, "imitate": "", "imitation_radius": 0,
                             "guard_drop": 0.0, "guard_restart": 0, "schedule_end": 0}
    cpu = make_config("cpu")
    assert {name: getattr(cpu, name) for name in OFF_SPELLINGS} == dict.fromkeys(OFF_SPELLINGS) | {"clip": 0.2}
    assert make_config("paper").learning_agents == 8 and make_config("paper").clip is None
    assert make_config("cpu", **OFF_SPELLINGS) == make_config("cpu", **dict.fromkeys(OFF_SPELLINGS))
    assert dataclasses.replace(cpu, guard_drop=0.6, learning_agents=16).guard_drop == 0.6
    assert dataclasses.replace(cpu, guard_drop=0, learning_agents=-1) == cpu


@pytest.mark.parametrize("settings, message", [
    ({"guard_drop": 1.0}, "guard_drop must be in (0, 1), or None or 0 for off, not 1.0"),
    ({"weight_average": -0.5}, "weight_average must be in (0, 1), or None or 0 for off, not -0.5"),
    ({"clip": -0.2}, "clip must be > 0, or None or 0 for off, not -0.2"),
    ({"guard_restart": -1}, "guard_restart must be > 0, or None or 0 for off, not -1"),
    ({"learning_agents": -2}, "learning_agents must be >= 1, or None or -1 for all, not -2")])
def test_a_setting_that_can_be_off_is_checked_when_on(settings, message):
    with pytest.raises(ValueError) as error:
        make_config("cpu", **settings)
    assert str(error.value) == message


def test_set_takes_none_or_the_old_spelling_for_off():
    old = parse_overrides(["guard_drop=0", "target_kl=0", "clip=0", "imitate=", "init_weights=",
                           "learning_agents=-1", "guard_restart=0", "imitation_radius=0", "weight_average=0",
                           "anneal_hold=0"])
    assert old == {"guard_drop": 0.0, "target_kl": 0.0, "clip": 0.0, "imitate": "", "init_weights": "",
                   "learning_agents": -1, "guard_restart": 0, "imitation_radius": 0, "weight_average": 0.0,
                   "anneal_hold": 0.0}
    assert make_config("cpu", **old) == make_config("cpu", clip=None)
    assert parse_overrides(["guard_drop=None", "imitate=none"]) == {"guard_drop": None, "imitate": None}
    on = parse_overrides(["guard_drop=0.6", "guard_restart=480", "imitate=csaf11", "clip=0.1", "target_kl=1"])
    assert on == {"guard_drop": 0.6, "guard_restart": 480, "imitate": "csaf11", "clip": 0.1, "target_kl": 1.0}
    assert [type(on[k]) for k in ("guard_restart", "target_kl")] == [int, float]
    with pytest.raises(ValueError, match="guard_restart expects an integer, got '4.5'"):
        parse_overrides(["guard_restart=4.5"])


@pytest.mark.parametrize("run, expected", [
    ("cpu-v3", {"learning_agents": None, "clip": 0.2, "target_kl": None, "weight_average": None,
                "init_weights": "runs/init/cpu-v2.pt", "guard_drop": None}),
    ("paper-novalid", {"learning_agents": 16, "weight_average": None, "imitate": None, "imitation_radius": None,
                       "init_weights": "models/training/paper-novalid/init.pt", "guard_restart": None})])
def test_config_files_written_before_load_with_none_for_off_and_are_written_with_null(run, expected, tmp_path):
    cfg = load_train_config(TRAINING / run / "config.json")
    assert {name: getattr(cfg, name) for name in expected} == expected
    written = tmp_path / "config.json"
    written.write_text(json.dumps(cfg.to_dict(), indent=2))
    assert '"guard_drop": null' in written.read_text() and load_train_config(written) == cfg


def test_a_recipe_writes_zero_for_off_its_stage_keeps_the_zero_and_its_configuration_holds_none():
    v2 = load_recipe("paper-v2")
    index = [s.name for s in v2.stages].index("nonlearning")
    assert v2.stages[index].settings["guard_drop"] == 0.0  # as written: the identity holds it
    assert '"guard_drop": 0.0' in v2.identity
    assert stage_config(v2, index, Path("run"), seed=1).guard_drop is None
    assert stage_config(v2, 0, Path("run"), seed=1).init_weights is None  # from scratch


def test_every_shipped_recipe_keeps_its_identity():
    found = {}
    for path in sorted(SHIPPED.glob("*.toml")):
        switches = ("",) + load_recipe(path.stem).switches
        found[path.stem] = digest(" ".join(digest(load_recipe(path.stem, switch, scale).identity)
                                           for switch in switches for scale in (1.0, 0.5, 0.25)))
    assert found == SHIPPED_IDENTITIES


def test_every_committed_runs_claim_is_its_recipes_identity_today():
    claims = sorted(TRAINING.glob("**/recipe.json"))
    assert len(claims) >= 20
    for claim in claims:
        held = json.loads(claim.read_text())
        parsed = parse_recipe(tomllib.loads(held["text"]), Path(held["recipe"]), held["text"],
                              held.get("switch", ""), held.get("scale", 1.0))
        assert parsed.identity == held_identity(held), claim


def test_a_checkpoint_written_before_resumes_under_its_config_and_a_changed_setting_is_still_refused(tmp_path):
    """The cpu-v3 run's checkpoint (the one run that keeps its latest.pt): it holds -1 for
    "every agent learns", from before None meant off."""
    stored = read_checkpoint(TRAINING / "cpu-v3" / "latest.pt")
    assert stored["train_config"]["learning_agents"] == -1
    assert off_as_none(stored["train_config"])["learning_agents"] is None
    run = tmp_path / "cpu-v3"
    run.mkdir()
    shutil.copy(TRAINING / "cpu-v3" / "latest.pt", run / "latest.pt")
    cfg = load_train_config(TRAINING / "cpu-v3" / "config.json")
    learner = Learner(cfg, run, log=lambda line: None)
    learner.writer.close()
    assert (learner.episode, learner.updates) == (stored["progress"]["episode"], stored["progress"]["updates"])
    assert json.loads((run / "config.json").read_text())["learning_agents"] is None
    with pytest.raises(CheckpointError, match=r"different settings \(learning_agents\)"):
        Learner(dataclasses.replace(cfg, learning_agents=8), run, log=lambda line: None)
