"""A topic counts as recorded only when the recorder's own reader has matched its publisher:
DDS matches the two ends separately, so the writer's count alone can be ahead (the race that
lost steps 0-1 of a few per-agent topics on a loaded machine). Real DDS, in a spawned process."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from ros_helpers import Spawner, fresh_domain_id  # noqa: E402

SCRIPT = """
import json, sys, time, rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64, String
from formic_record.bag import BagWriter
from formic_ros import qos
import formic_topics as topics
from formic_ros.graph import REPORT_GRAPH_LAG_S, RecorderReports, recorders_matched
from formic_ros.recording.recorder import Recorder, RecorderOptions

rclpy.init(domain_id=int(sys.argv[1]))
executor = SingleThreadedExecutor()
world = rclpy.create_node("world", namespace="/formic")
score = world.create_publisher(Float64, "score", qos.LOG)
reports = RecorderReports(world)
executor.add_node(world)
results = {}

def spin_until(check, seconds=20.0):
    end = time.monotonic() + seconds
    while not check():
        if time.monotonic() > end:
            return False
        executor.spin_once(timeout_sec=0.02)
    return True

def matched():
    return recorders_matched(world, [score], 1, reports)

# A node named recorder whose reader the writer counts, but which reports nothing: not recorded.
silent = rclpy.create_node("recorder", namespace="/formic")
silent.create_subscription(Float64, "score", lambda m: None, qos.LOG)
executor.add_node(silent)
results["writer_matched"] = spin_until(lambda: score.get_subscription_count() == 1)
results["silent"] = spin_until(matched, 1.0)
report = silent.create_publisher(String, topics.RECORDER_MATCHES, qos.LATCHED)
report.publish(String(data="not json"))
own_id = "/formic/recorder#1-silent"
report.publish(String(data=json.dumps({"recorder": own_id, "publishers": {"/formic/score": 0}})))
results["reports_none_matched"] = spin_until(matched, 1.0)
report.publish(String(data=json.dumps({"recorder": "/elsewhere/recorder#2-x", "publishers": {"/formic/score": 1}})))
results["another_nodes_report"] = spin_until(matched, 1.0)
report.publish(String(data=json.dumps({"recorder": own_id, "publishers": {"/formic/score": 1}})))
results["reports_matched"] = spin_until(matched, 5.0)
executor.remove_node(silent)
silent.destroy_node()
results["silent_gone"] = spin_until(lambda: score.get_subscription_count() == 0)

# Its report stays in the table (latched, no goodbye); a new silent recorder is not covered by it,
# and once the report is older than the graph's lag it is dropped, so the next recorder reports itself.
again = rclpy.create_node("recorder", namespace="/formic")
again.create_subscription(Float64, "score", lambda m: None, qos.LOG)
executor.add_node(again)
results["again_matched"] = spin_until(lambda: score.get_subscription_count() == 1)
results["stale_report"] = spin_until(matched, REPORT_GRAPH_LAG_S + 0.5)
executor.remove_node(again)
again.destroy_node()
spin_until(lambda: score.get_subscription_count() == 0)

# The real recorder: its report comes by itself, and is not recorded.
writer = BagWriter(sys.argv[2])
recorder = Recorder(writer, RecorderOptions())
executor.add_node(recorder)
results["recorder_matched"] = spin_until(matched)
results["report"] = reports.reports[recorder.recorder_id][1].get("/formic/score")
score.publish(Float64(data=1.5))
spin_until(lambda: recorder.counts["/formic/score"] == 1, 5.0)
results["counts"] = dict(recorder.counts)
writer.close()
print(json.dumps(results), flush=True)
rclpy.shutdown()
"""


def test_a_topic_is_recorded_only_once_the_recorder_reports_its_reader_matched(tmp_path):
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        proc = spawner.python("script", "-c", SCRIPT, str(spawner.domain_id), str(tmp_path / "rec"), limit_s=90)
        assert proc.wait() == 0, proc.output()[-3000:]
        results = proc.json_line()
    finally:
        spawner.reap_all()
    assert results["writer_matched"], "the silent recorder's reader never matched"
    assert not results["silent"], "a writer-side match alone counted as recorded"
    assert not results["reports_none_matched"], "a report of 0 matched publishers counted as recorded"
    assert not results["another_nodes_report"], "a report in the name of a node not in the graph counted"
    assert results["silent_gone"] and results["again_matched"]
    assert not results["stale_report"], "a departed recorder's report counted for a new one"
    assert results["reports_matched"] and results["recorder_matched"]
    assert results["report"] == 1
    assert results["counts"] == {"/formic/score": 1}, "the recorder recorded its own report or missed the score"
    assert "malformed report" in proc.output()
