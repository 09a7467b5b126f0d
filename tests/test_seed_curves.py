"""analysis/seed_curves.py: a recipe's seeds read from their logs alone, resumed lines replaced."""

from __future__ import annotations

import json

from click.testing import CliRunner

from analysis.seed_curves import main, read_seed, stage_rows


def line(stage: str, episode: int, food: float, entropy: float = 1.0, valid: float = 0.5, kl: float = 0.01) -> str:
    return (f"{stage}: ep {episode:6d} | food {food:6.1f} (1 2) | loss 0.1 pi 0.0 v 0.0 ent {entropy:.3f} "
            f"valid {valid:.3f} act-ok 0.90 | kl {kl:.4f} upd 1.00 | I_h 1.00 | 1,000 agent-steps/s | 1.0 min")


def write_run(folder, seed: str, lines: list[str], finished: dict[str, int]) -> None:
    (folder / f"{seed}.log").parent.mkdir(parents=True, exist_ok=True)
    (folder / f"{seed}.log").write_text("\n".join(lines) + "\n")
    for stage, episode in finished.items():
        (folder / seed / stage).mkdir(parents=True)
        (folder / seed / stage / "progress.json").write_text(json.dumps({"episode": episode}))


def test_stages_lie_end_to_end_and_a_resumed_episode_replaces_the_first_one_logged(tmp_path):
    write_run(tmp_path, "seed1", [
        "stage 1/2 first: 8 episodes from scratch | recipe 0/20 episodes",
        line("first", 4, 10.0), line("first", 8, 30.0, kl=0.02),
        "first: resumed from x/latest.pt: episode 4, update 4",
        line("first", 8, 20.0),
        "stage 2/2 second: 12 episodes from first (a fresh optimiser)",
        line("second", 4, 40.0), line("second", 8, 10.0), line("second", 12, 30.0)], {"first": 8})
    seed = read_seed(tmp_path / "seed1.log", tmp_path / "seed1")
    assert seed.stages == ["first", "second"] and seed.lengths == {"first": 8, "second": 12}
    assert seed.points["first"][8] == {"food": 20.0, "entropy": 1.0, "valid": 0.5, "kl": 0.01}
    assert seed.offsets() == {"first": 0, "second": 8}
    # rolling means within 8 episodes: first 10, 15; second 40, 25, 20, of which full windows
    # (from episode 8 on) count: first 15; second 25, then 20 (a fall of 20% after its best)
    assert stage_rows(seed, window=8) == [("first", 8, 15.0, 0.0), ("second", 12, 20.0, 1 - 20 / 25)]
    # within 40 episodes no window of these short stages is full: their last mean stands alone
    assert stage_rows(seed) == [("first", 8, 15.0, 0.0), ("second", 12, 80 / 3, 0.0)]


def test_a_copied_stage_is_read_from_the_run_it_came_from_and_the_table_printed(tmp_path):
    write_run(tmp_path / "old", "seed2", ["stage 1/1 first: 8 episodes", line("first", 4, 6.0), line("first", 8, 8.0)],
              {})
    write_run(tmp_path / "new", "seed2", ["stage 1/2 first: complete (8 episodes), skipped",
                                          "stage 2/2 second: 4 episodes from first", line("second", 4, 12.0)],
              {"first": 8, "second": 4})
    out = tmp_path / "figure.png"
    result = CliRunner().invoke(main, [str(tmp_path / "new"), "--stages-from", str(tmp_path / "old"),
                                       "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines() == [
        "| seed | stage | episodes | food, last 40 episodes | deepest fall after its best |",
        "|---|---|---|---|---|",
        "| seed2 | first | 8 | 7.0 | 0% |",
        "| seed2 | second | 4 | 12.0 | 0% |",
        f"wrote {out}"]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    alone = CliRunner().invoke(main, [str(tmp_path / "new")])
    assert "| seed2 | first |" not in alone.output and "| seed2 | second | 4 | 12.0 | 0% |" in alone.output
    empty = CliRunner().invoke(main, [str(tmp_path)])
    assert empty.exit_code == 2 and "has no seedS.log" in empty.output
