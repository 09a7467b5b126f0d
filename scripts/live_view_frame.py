"""Render a frame of the live view as a viewer receives it (the README's picture).

Starts ``formic sim --view --view-wait``, connects as a Foxglove WebSocket client, subscribes
to every channel, decodes the messages with their advertised schemas and draws the last world
grid, the agents and the food curves with matplotlib, laid out like foxglove/formic_layout.json.
(No browser build of Foxglove or Lichtblick can be installed here, hence a rendered frame.)

Usage: .venv/bin/python scripts/live_view_frame.py [--out docs/live_view.png] [sim options...]
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def decoder(channel: dict):
    if channel["encoding"] == "json":
        return json.loads
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"])).file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"])).FromString


def watch(url: str) -> dict[str, list]:
    """Every decoded message, by topic, until the server closes."""
    got: dict[str, list] = {}
    for _ in range(300):  # the server may still be starting
        try:
            connection = connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None)
            break
        except OSError:
            time.sleep(0.1)
    with connection as ws:
        channels: dict[int, dict] = {}
        while len(channels) < 4:
            op = json.loads(ws.recv(timeout=30))
            if op["op"] == "advertise":
                channels.update({c["id"]: c | {"decode": decoder(c)} for c in op["channels"]})
        subs = dict(enumerate(channels))
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": c} for i, c in subs.items()]}))
        try:
            while True:
                frame = ws.recv(timeout=120)
                if isinstance(frame, bytes) and frame[0] == 1:
                    sub, stamp = struct.unpack_from("<IQ", frame, 1)
                    channel = channels[subs[sub]]
                    got.setdefault(channel["topic"], []).append((stamp / 1e9, channel["decode"](frame[13:])))
        except Exception as exc:  # closed: the run is over
            if not type(exc).__name__.startswith("ConnectionClosed"):
                raise
    return got


def draw(got: dict[str, list], out: Path, title: str) -> None:
    _, grid = got["/formic/world"][-1]
    cells = np.frombuffer(grid.data, dtype=np.uint8).reshape(-1, grid.column_count, grid.cell_stride)
    offsets = {f.name: f.offset for f in grid.fields}
    rgba = np.stack([cells[..., offsets[c]] for c in ("red", "green", "blue", "alpha")], axis=-1)
    _, scene = got["/formic/agent_markers"][-1]
    states = [m for _, m in got["/formic/state"]]

    fig = plt.figure(figsize=(13, 7.2), dpi=110, facecolor="#f4f4f6")
    fig.suptitle(title, fontsize=11)
    ax = fig.add_axes((0.02, 0.04, 0.58, 0.86))
    height, width = rgba.shape[:2]
    ax.imshow(rgba, origin="lower", extent=(0, width, 0, height), interpolation="nearest")
    for shape, marker in (("spheres", "o"), ("cubes", "s")):
        prims = [p for e in scene.entities for p in getattr(e, shape)]
        if prims:
            ax.scatter([p.pose.position.x for p in prims], [p.pose.position.y for p in prims], s=22, marker=marker,
                       c=[(p.color.r, p.color.g, p.color.b) for p in prims], edgecolors="black", linewidths=0.4)
    ax.set_title("3D: /formic/world (foxglove.Grid) + /formic/agent_markers (SceneUpdate)", fontsize=9)
    ax.set_xticks([]), ax.set_yticks([])

    plot = fig.add_axes((0.66, 0.42, 0.32, 0.46))
    plot.plot([s["sim_time"] for s in states], [s["score"] for s in states],
              label="food delivered (/formic/score.data)")
    plot.plot([s["sim_time"] for s in states], [s["food_carried"] for s in states],
              label="food carried (/formic/state.food_carried)")
    plot.set_xlabel("sim time [s]"), plot.legend(fontsize=8), plot.grid(alpha=0.3)
    plot.set_title("Plot", fontsize=9)

    raw = fig.add_axes((0.66, 0.04, 0.32, 0.28))
    raw.axis("off")
    last = states[-1]
    raw.set_title("Raw messages: /formic/state", fontsize=9)
    raw.text(0.02, 0.95, json.dumps(last, indent=1), va="top", family="monospace", fontsize=8,
             transform=raw.transAxes)
    fig.savefig(out, facecolor=fig.get_facecolor())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "live_view.png"))
    args, sim_args = parser.parse_known_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sim_args = sim_args or ["--policy", "formic", "--agents", "32", "--size", "128", "--steps", "512"]
    command = [sys.executable, "-m", "formic_cli.main", "sim", *sim_args, "--view", "--view-port", str(port),
               "--view-wait", "--out", "/tmp/formic-live-view-frame", "--json"]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    process = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        got = watch(f"ws://127.0.0.1:{port}")
        summary = json.loads(process.communicate(timeout=120)[0].decode().strip().splitlines()[-1])
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    h, w = summary["size"]
    title = (f"formic sim --view: {summary['policy']}, {summary['agents']} agents, {h}x{w}, step {summary['steps']}, "
             f"food {summary['food']:g}  (rendered from the decoded live stream, not a browser screenshot)")
    draw(got, Path(args.out), title)
    print(f"wrote {args.out} ({sum(map(len, got.values()))} messages)")


if __name__ == "__main__":
    main()
