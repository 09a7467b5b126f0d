"""docs/layout.md's rule: the packages without ROS import no rclpy, and neither does the launch
layer (it starts the processes that do), so the core, the policies, training, evaluation and the
launcher work, and stay fast to import, where ROS is absent."""

from __future__ import annotations

import json
import subprocess
import sys

ROS_FREE = ("formic_world", "formic_agent", "formic_baselines", "formic_runtime", "formic_trainer", "formic_eval",
            "formic_record", "formic_robots", "formic_topics", "formic_view", "formic_ros.launch")

IMPORT_ALL = """
import importlib, json, pkgutil, sys
imported = []
for name in sys.argv[1:]:
    package = importlib.import_module(name)
    imported.append(name)
    for module in pkgutil.walk_packages(package.__path__, name + "."):
        importlib.import_module(module.name)
        imported.append(module.name)
ros = sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "rosidl_runtime_py"))
print(json.dumps({"imported": imported, "ros": ros}))
"""


def test_the_packages_without_ros_import_no_rclpy():
    done = subprocess.run([sys.executable, "-c", IMPORT_ALL, *ROS_FREE], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)
    assert "formic_runtime.signals" in result["imported"] and "formic_ros.launch.processes" in result["imported"]
    assert result["ros"] == []
