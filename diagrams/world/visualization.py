"""Meshcat: live view and self-contained HTML replays."""
from pathlib import Path

from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Role


def add_meshcat_visualizer(builder, scene_graph, meshcat: Meshcat):
    """Illustration geometry of the scene, published at 30 Hz."""
    return MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(
        role=Role.kIllustration, publish_period=1 / 30))


def start_recording(meshcat: Meshcat) -> None:
    meshcat.StartRecording(frames_per_second=30.0, set_visualizations_while_recording=True)


def write_recording(meshcat: Meshcat, filename: str | Path) -> Path:
    """Stops the recording and writes a replay that opens in a browser without a server."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    path = Path(filename)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(meshcat.StaticHtml())
    return path
