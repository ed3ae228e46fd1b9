"""twin.glb: the twin at its canonical state as binary glTF, for web viewers, Blender and slides:
one named node per link ("static" and each part), each part node at its link frame."""

from __future__ import annotations

from pathlib import Path

import trimesh

from funrec.export.sim_model import SimModel


def glb_scene(model: SimModel) -> trimesh.Scene:
    """The model as a trimesh scene: node ``static`` (export frame) and a node per part whose
    transform is the part's link frame ``T_export_part`` (its z axis is the joint axis, so turning
    or sliding the node about its own z moves the part as its joint does), meshes in link frames
    with their vertex colours."""
    scene = trimesh.Scene()
    for link in (model.base, *model.parts):
        if link.visual is None:
            continue
        scene.add_geometry(link.visual, node_name=link.name, geom_name=link.name, transform=link.T_export_link)
    return scene


def write_glb(model: SimModel, path: str | Path) -> Path:
    """Write twin.glb (see :func:`glb_scene`).

    Args:
        model: the simulator-neutral model.
        path: output file.

    Returns:
        ``path``.
    """
    path = Path(path)
    path.write_bytes(glb_scene(model).export(file_type="glb"))
    return path


__all__ = ["glb_scene", "write_glb"]
