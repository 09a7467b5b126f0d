"""FORMIC_TIMELINE: the marks each process writes, and how ``segments`` splits a step's round
trip across the world's and the hosts' files (no ROS here; the real run is in
tests/test_ros_system.py)."""

from __future__ import annotations

import pytest

from formic_ros import timeline
from formic_ros.timeline import ENV, LAST_SEGMENT, PATH, Timeline, segments

WORLD = ("observe", "sent", "heard", "stepped")
HOST = ("all_in", "decide", "decided", "answered")


def write(folder, name, rows):
    folder.mkdir(exist_ok=True)
    (folder / name).write_text("event,step,ns\n" + "".join(f"{e},{s},{ns}\n" for e, s, ns in rows))


def step_marks(step: int, start_ms: float, host_offsets_ms: tuple[float, ...]) -> tuple[list, list]:
    """World and host marks of one step: observe at ``start_ms``, sent +1, the host's four marks
    at the offsets, heard and stepped 0.5 and 1.0 ms after the host's last."""
    ms = 1_000_000
    world = [("observe", step, int(start_ms * ms)), ("sent", step, int((start_ms + 1) * ms))]
    host = [(e, step, int((start_ms + off) * ms)) for e, off in zip(HOST, host_offsets_ms)]
    last = start_ms + host_offsets_ms[-1]
    world += [("heard", step, int((last + 0.5) * ms)), ("stepped", step, int((last + 1.0) * ms))]
    return world, host


def test_the_segments_of_a_step_add_up_to_the_step_and_come_from_the_host_that_answered_last(tmp_path):
    world, fast, slow = [], [], []
    for step in range(5):  # a step every 10 ms: 1 ms to send, host marks at 1.5/2/6/7 (slow) ms
        w, h_slow = step_marks(step, 10.0 * step, (1.5, 2.0, 6.0, 7.0))
        _, h_fast = step_marks(step, 10.0 * step, (1.2, 1.4, 3.0, 3.5))
        world += w
        slow += h_slow
        fast += h_fast
    write(tmp_path, "world-1.csv", world)
    write(tmp_path, "host-2.csv", fast)
    write(tmp_path, "host-3.csv", slow)
    report = segments(tmp_path)
    assert report["steps"] == 3 and report["hosts"] == 2  # steps 1-3: step 0 and the last left out
    assert report["cycle_ms"] == pytest.approx(10.0)
    assert list(report["segments_ms"]) == [label for _, _, label in PATH] + [LAST_SEGMENT]
    assert list(report["segments_ms"].values()) == pytest.approx([1.0, 0.5, 0.5, 4.0, 1.0, 0.5, 0.5, 2.0])


def test_a_folder_without_one_world_and_its_hosts_is_refused(tmp_path):
    with pytest.raises(ValueError, match="holds 0 world and 0 host timelines"):
        segments(tmp_path)
    w, h = step_marks(0, 0.0, (1, 2, 3, 4))
    write(tmp_path, "world-1.csv", w)
    write(tmp_path, "world-2.csv", w)
    write(tmp_path, "host-3.csv", h)
    with pytest.raises(ValueError, match="holds 2 world and 1 host timelines: .* fresh DIR"):
        segments(tmp_path)
    (tmp_path / "world-2.csv").unlink()
    with pytest.raises(ValueError, match="no step has every mark"):
        segments(tmp_path)
    (tmp_path / "host-3.csv").write_text("step,event\n")
    with pytest.raises(ValueError, match="host-3.csv is not a timeline file"):
        segments(tmp_path)


def test_marks_are_kept_only_while_the_variable_names_a_folder(tmp_path, monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    off = Timeline("world")
    off.mark("observe", 1)
    assert off.mark is timeline._ignore and off.save() is None and not list(tmp_path.iterdir())
    monkeypatch.setenv(ENV, str(tmp_path / "tl"))
    on = Timeline("host")
    for event in HOST:
        on.mark(event, 7)
    path = on.save()
    assert path.parent == tmp_path / "tl" and path.name.startswith("host-")
    assert [line.split(",")[:2] for line in path.read_text().splitlines()] == [["event", "step"]] + [
        [e, "7"] for e in HOST]
    assert on.save() is None  # written once
