"""Ghosts of a part in the static scene (``funrec_robot.ghosts``): found inside the part's sweep or on its
handle's path, real furniture beside the part kept, and hidden from collisions on a copy of the model."""

from __future__ import annotations

import mujoco
import numpy as np

from funrec_robot.ghosts import GHOST_TOLERANCE_M, part_ghosts, range_states, without_geoms

DOOR_HALF = np.array([0.25, 0.01, 0.35])
"""Half-size of the door panel, m: 0.5 m wide, hinged at x = 0 on its left edge, opening about -z."""
P_WORLD_CONTACT = np.array([0.45, -0.05, 0.4])
"""The handle's contact point at state 0, m: 4 cm in front of the door, near its free edge."""


def _door_at(state: float) -> tuple[np.ndarray, np.ndarray]:
    """(centre, quat_wxyz) of the door panel at ``state`` rad (hinge axis -z through the origin)."""
    c, s = np.cos(-state), np.sin(-state)
    centre = np.array([c * 0.25, s * 0.25, 0.4])
    return centre, np.array([np.cos(-state / 2), 0.0, 0.0, np.sin(-state / 2)])


def _contact_at(state: float) -> np.ndarray:
    c, s = np.cos(-state), np.sin(-state)
    p = P_WORLD_CONTACT
    return np.array([c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]])


def _scene(ghost_shift: float = 0.0, ghost_inset: float = 0.02, hand: bool = True) -> mujoco.MjModel:
    """The door, its carcass and a wall, a copy of the door at 1.2 rad (``ghost_shift`` up its hinge, each
    side ``ghost_inset`` smaller) and, with ``hand``, the demonstrator's hand on the handle at 0.8 rad."""
    ghost_centre, ghost_quat = _door_at(1.2)
    ghost_centre = ghost_centre + [0.0, 0.0, ghost_shift]
    p_hand = _contact_at(0.8)
    q = " ".join(f"{v:.9f}" for v in ghost_quat)
    hand_geom = f'<geom name="hand_ghost" type="box" pos="{p_hand[0]} {p_hand[1]} {p_hand[2]}" size="0.02 0.02 0.03"/>'
    return mujoco.MjModel.from_xml_string(f"""
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    <body name="static">
      <geom name="carcass" type="box" pos="0.25 0.3 0.4" size="0.25 0.28 0.36"/>
      <geom name="wall" type="box" pos="-0.2 -0.4 1.0" size="0.05 0.4 1.0"/>
      <geom name="door_ghost" type="box" pos="{ghost_centre[0]} {ghost_centre[1]} {ghost_centre[2]}" quat="{q}"
            size="{DOOR_HALF[0] - ghost_inset} {DOOR_HALF[1]} {DOOR_HALF[2] - ghost_inset}"/>
      {hand_geom if hand else ""}
      <geom name="display" type="box" pos="0.3 -0.3 0.4" size="0.3 0.3 0.3" contype="0" conaffinity="0"/>
    </body>
    <body name="part_0">
      <joint name="part_0" type="hinge" axis="0 0 -1" range="0 1.5"/>
      <geom name="panel" type="box" pos="0.25 0 0.4" size="{DOOR_HALF[0]} {DOOR_HALF[1]} {DOOR_HALF[2]}"/>
    </body>
  </worldbody>
  <contact><exclude body1="static" body2="part_0"/></contact>
</mujoco>""")


def test_ghosts_are_the_copies_of_the_part_and_of_the_hand_on_its_handle_not_the_furniture() -> None:
    model = _scene()
    joint = model.joint("part_0").id
    ghosts = part_ghosts(model, joint, range_states(model, joint, (0.0, 1.5)), P_WORLD_CONTACT)
    names = sorted(model.geom(int(g)).name for g in ghosts)
    # The carcass the door closes against and the wall beside its swing are furniture; a geom that does not
    # collide (a twin's display mesh) is never an obstacle, so never a ghost.
    assert names == ["door_ghost", "hand_ghost"]


def test_no_ghost_where_the_part_never_goes() -> None:
    model = _scene()
    joint = model.joint("part_0").id
    # Opened only to 0.6 rad the door never reaches its copy at 1.2 rad, nor the handle the hand at 0.8 rad.
    assert len(part_ghosts(model, joint, range_states(model, joint, (0.0, 0.6)), P_WORLD_CONTACT)) == 0


def test_range_states_keep_the_parts_far_corner_within_twice_the_tolerance() -> None:
    model = _scene()
    joint = model.joint("part_0").id
    states = range_states(model, joint, (0.0, 1.5))
    radius = float(np.hypot(2 * DOOR_HALF[0], DOOR_HALF[1]))
    assert states[0] == 0.0 and states[-1] == 1.5
    assert np.max(np.diff(states)) * radius <= 2 * GHOST_TOLERANCE_M + 1e-9


def test_without_geoms_hides_them_from_collisions_on_a_copy() -> None:
    model = _scene()
    joint = model.joint("part_0").id
    ghosts = part_ghosts(model, joint, range_states(model, joint, (0.0, 1.5)), P_WORLD_CONTACT)
    hidden = without_geoms(model, ghosts)
    assert np.all(hidden.geom_contype[ghosts] == 0) and np.all(hidden.geom_conaffinity[ghosts] == 0)
    assert np.all(model.geom_contype[ghosts] == 1), "the caller's model must be left as it was"
    assert without_geoms(model, []) is model


def test_hull_approximated_tells_a_twins_part_from_a_scene_of_primitives() -> None:
    from funrec_robot.scene import hull_approximated

    model = _scene()
    assert not hull_approximated(model, model.joint("part_0").id)
    # A twin's part: a mesh to show (colliding with nothing) and convex pieces of it to collide.
    twin = mujoco.MjModel.from_xml_string("""
<mujoco>
  <asset><mesh name="shown" vertex="0 0 0  0.5 0 0  0 0 0.7  0.5 0 0.7  0 0.02 0  0.5 0.02 0  0 0.02 0.7  0.5 0.02 0.7"/></asset>
  <worldbody>
    <body name="part_0">
      <joint name="part_0" type="hinge" axis="0 0 -1" range="0 1.5"/>
      <geom name="part_0_visual" type="mesh" mesh="shown" contype="0" conaffinity="0"/>
      <geom name="part_0_collision_000" type="box" pos="0.25 0.01 0.35" size="0.25 0.01 0.35"/>
    </body>
  </worldbody>
</mujoco>""")
    assert hull_approximated(twin, twin.joint("part_0").id)


def test_a_copy_fused_two_centimetres_off_the_part_is_a_ghost() -> None:
    """A twin's copy of the part sits off the part by up to the fusion voxels (1 cm static, 5 mm part) and what
    the twin's joint misses of where the part was while it was held (a degree of state: 0.9 cm at the 0.5 m
    door's edge): a copy of the door at 1.2 rad, full size, shifted 2 cm along the hinge, where no other state of
    the door covers it, is a ghost; the carcass and the wall stay furniture."""
    model = _scene(ghost_shift=0.02, ghost_inset=0.0, hand=False)
    joint = model.joint("part_0").id
    # The contact point is put 2 m below the door, where its path crosses no geom: the copy must be told by its
    # vertices alone (the handle's path through a copy of the door is the other rule).
    ghosts = part_ghosts(model, joint, range_states(model, joint, (0.0, 1.5)), P_WORLD_CONTACT - [0.0, 0.0, 2.0])
    assert sorted(model.geom(int(g)).name for g in ghosts) == ["door_ghost"]
