"""The scene directory format, cameras, trajectories and structure maps.

``load_scene`` / ``write_scene`` / ``Scene`` are the format (see ``docs/scene-format.md``);
``cameras``, ``trajectories`` and ``structure`` are imported from their modules.
"""

from recondreamer.scene.format import FORMAT_VERSION, Scene, load_scene, write_scene

__all__ = ["FORMAT_VERSION", "Scene", "load_scene", "write_scene"]
