"""Session 17 check, run from a worktree of 47af1fe: the half-length reference stage of the first
tables reference row (its config, check-whole-basics-config.json) started from recipe seed 1's
whole basics stage instead of its own halved one.

Usage: PYTHONPATH=WORKTREE/src python check-whole-basics.py INIT_PT OUT_DIR EPISODES
"""
import json
import sys
from pathlib import Path

from formic_trainer.config import TrainConfig
from formic_trainer.train import Trainer

settings = json.loads((Path(__file__).parent / "check-whole-basics-config.json").read_text())
settings["init_weights"] = sys.argv[1]
Trainer(TrainConfig(**settings), Path(sys.argv[2]), resume=False).train(episodes=int(sys.argv[3]))
