"""Live view of a run in Foxglove or Lichtblick, without ROS (see :mod:`formic_view.live`).

The constants import without foxglove-sdk, so the command line stays quick to start."""

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
DEFAULT_MAX_HZ = 10.0


def address(host: str, port: int) -> str:
    return f"ws://{host}:{port}"


def announcement(url: str) -> str:
    return f"live view: {url} (open in Foxglove or Lichtblick: Open connection -> Foxglove WebSocket)"


def __getattr__(name: str):
    if name == "LiveView":
        from .live import LiveView

        return LiveView
    raise AttributeError(name)


__all__ = ["DEFAULT_HOST", "DEFAULT_MAX_HZ", "DEFAULT_PORT", "LiveView", "address", "announcement"]
