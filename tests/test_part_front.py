"""The front of a part read off its geoms when it is not a thin panel with the handle in front of it: a drawer
that is one thick box (Meta-World's), a handle on posts reaching past the panel's edge (Meta-World's door)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from funrec.errors import PlanningError
from funrec_robot.scene import part_front

SCENE = """
<mujoco>
  <worldbody>
    <body name="unit" pos="0 1 0.5">
      <geom type="box" size="0.4 0.3 0.5"/>
      <body name="part" pos="0 -0.3 0">
        <joint name="part_0" type="{joint}" axis="{axis}" range="0 1"/>
        {geoms}
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _front(joint: str, axis: str, geoms: str, contact: list[float]):
    model = mujoco.MjModel.from_xml_string(SCENE.format(joint=joint, axis=axis, geoms=geoms))
    return part_front(model, model.joint("part_0").id, contact)


def test_a_drawer_that_is_one_thick_box_faces_its_handle() -> None:
    # The drawer's body, 0.3 m deep, reaches out of the unit towards -y; a bar on its front at y = -0.16.
    drawer = '<geom type="box" pos="0 0.1 0" size="0.3 0.2 0.2"/><geom type="box" pos="0 -0.13 0" size="0.15 0.03 0.012"/>'
    front = _front("slide", "0 -1 0", drawer, [0.0, 0.57, 0.5])
    np.testing.assert_allclose(front.normal_world, [0.0, -1.0, 0.0], atol=1e-9)
    assert front.standoff == pytest.approx(0.03, abs=1e-6)  # from the bar's centre back to the drawer's face
    assert front.handle_width == pytest.approx(0.024, abs=1e-6)


def test_a_handle_reaching_past_the_doors_edge_faces_the_door_not_its_edge() -> None:
    # A 2 cm door from x = -0.4 to 0.4 at y = 0.7; the handle (one box with its posts, as a mesh's box is)
    # reaches from the door to 0.2 m in front of it, its contact 3 cm past the door's edge (beyond
    # PANEL_MARGIN_M). The handle's box overlaps both the door's front and its edge face; the edge face is
    # nearer (3 cm) than the front (0.19 m), but the contact point projects onto the front.
    door = '<geom type="box" pos="0 0 0" size="0.4 0.01 0.3"/><geom type="box" pos="0.42 -0.1 0" size="0.05 0.1 0.01"/>'
    front = _front("hinge", "0 0 1", door, [0.43, 0.5, 0.5])
    np.testing.assert_allclose(front.normal_world, [0.0, -1.0, 0.0], atol=1e-9)
    assert front.standoff == pytest.approx(0.19, abs=1e-6)


def test_a_contact_point_away_from_the_part_is_still_refused() -> None:
    with pytest.raises(PlanningError, match="no front panel"):
        _front("hinge", "0 0 1", '<geom type="box" size="0.4 0.01 0.3"/>', [2.0, 0.0, 0.5])


def test_a_bars_ends_are_measured_from_the_contact_point_along_it() -> None:
    # An upright bar 0.5 m long on a door's front, its contact point 0.1 m above the bar's middle.
    door = '<geom type="box" size="0.4 0.01 0.5"/><geom type="box" pos="0.3 -0.03 0" size="0.0075 0.0075 0.25"/>'
    front = _front("hinge", "0 0 1", door, [0.3, 0.67, 0.6])
    np.testing.assert_allclose(front.handle_axis_world, [0.0, 0.0, 1.0], atol=1e-9)
    assert front.handle_extent == pytest.approx((-0.35, 0.15), abs=1e-9)
