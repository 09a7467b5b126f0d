"""scripts/average_checkpoints.py: the mean of one run's checkpoints."""

from __future__ import annotations

import pytest
import torch

from formic_agent.checkpoint import load_network, read_checkpoint, save_checkpoint
from formic_agent.inputs import NETWORK_PRESETS
from formic_agent.network import ForMICNet
from scripts.average_checkpoints import main


def test_the_average_is_the_mean_of_every_tensor_and_names_its_inputs(tmp_path):
    torch.manual_seed(0)
    paths = []
    for i in range(3):
        paths.append(str(tmp_path / f"ep{i}.pt"))
        save_checkpoint(paths[-1], ForMICNet(NETWORK_PRESETS["cpu"]))
    with pytest.raises(SystemExit) as done:
        main([*paths, "--out", str(tmp_path / "mean.pt")])
    assert done.value.code == 0
    mean, payload = load_network(tmp_path / "mean.pt")
    nets = [load_network(p)[0] for p in paths]
    for key, value in mean.state_dict().items():
        want = (nets[0].state_dict()[key] + nets[1].state_dict()[key] + nets[2].state_dict()[key]) / 3
        assert torch.allclose(value, want, atol=1e-7), key
    assert [name.split()[0] for name in read_checkpoint(tmp_path / "mean.pt")["averaged_from"]] == [
        "ep0.pt", "ep1.pt", "ep2.pt"]


def test_networks_of_different_shapes_are_refused_and_nothing_is_written(tmp_path, capsys):
    save_checkpoint(tmp_path / "a.pt", ForMICNet(NETWORK_PRESETS["cpu"]))
    save_checkpoint(tmp_path / "b.pt", ForMICNet(NETWORK_PRESETS["cpu-feedback"]))
    with pytest.raises(SystemExit) as done:
        main([str(tmp_path / "a.pt"), str(tmp_path / "b.pt"), "--out", str(tmp_path / "mean.pt")])
    assert done.value.code == 1 and "differs from" in capsys.readouterr().err
    assert not (tmp_path / "mean.pt").exists()
