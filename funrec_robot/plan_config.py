"""Settings of interaction planning, in one place for the planning steps that read them (``plan`` orders the
steps, ``whole_body`` solves the IK of one attempt)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from funrec_robot.grasp import GraspConfig
from funrec_robot.ik import IKConfig
from funrec_robot.retime import RetimeConfig
from funrec_robot.trajopt import PlacementConfig


@dataclass(frozen=True)
class PlanConfig:
    """Settings of interaction planning (nested: placement, IK, timing, grasp)."""

    placement: PlacementConfig = field(default_factory=PlacementConfig)
    """Base placement."""
    ik: IKConfig = field(default_factory=IKConfig)
    """Whole-body IK."""
    retime: RetimeConfig = field(default_factory=RetimeConfig)
    """Time parametrisation."""
    grasp: GraspConfig = field(default_factory=GraspConfig)
    """Grasp geometry."""
    pregrasp_distance: float = 0.10
    """The gripper comes onto the handle along the approach from this far out, m."""
    retreat_distance: float = 0.12
    """... and leaves it along the approach by this much (or as far as it can, see ``min_retreat_clearance``), m."""
    end_margin_rad: float = float(np.deg2rad(3.0))
    """'open' and 'close' stop this short of a revolute part's range ends (never drive it into its stop), rad; not
    where the part's weight carries it on to the end (a drop-down door: it comes to rest there anyway)."""
    end_margin_m: float = 0.02
    """... and this short of a prismatic part's, m."""
    pregrasp_dwell: float = 0.3
    """Pause at the pre-grasp pose so that the servos settle before the last approach, s."""
    effort_share_damping: float = 0.5
    """Share of a joint's effort limit its simulated damping may take at the planned speed."""
    effort_share_inertia: float = 0.3
    """Share of a joint's effort limit its armature may take at the planned acceleration."""
    gravity_effort_share: float = 0.9
    """Share of a joint's effort limit gravity may take anywhere along the handle path (the rest tracks)."""
    approach_scale: float = 0.6
    """Fraction of the speed and acceleration limits used to reach the pre-grasp pose (the servos then track
    within their effort limits, and within a centimetre)."""
    final_approach_scale: float = 0.3
    """Fraction of the speed and acceleration limits used from pre-grasp to grasp (a slow, precise move)."""
    handle_speed: float = 0.3
    """Largest speed of the handle while actuating, m/s."""
    handle_acceleration: float = 0.3
    """Largest acceleration of the handle along its path while actuating, m/s^2."""
    via_distance: float = 0.25
    """When the direct approach collides, the gripper first goes to this far out along the approach, m."""
    via_position_tolerance: float = 0.03
    """Largest IK residual accepted at the approach's via pose (free space), m."""
    approach_line_step: float = 0.1
    """Where the joint moves to the via pose collide, the hand goes to it along a straight line through IK poses this
    far apart, m (a joint move between poses 0.1 m apart keeps the hand within a few centimetres of the line)."""
    retreat_step: float = 0.01
    """The retreat is solved in steps of this length along the approach, stopping where the IK cannot follow, m."""
    release_sweep_samples: int = 8
    """Gripper commands from holding to released at which a robot's ``gripper.release_sweep`` is checked."""
    min_retreat_clearance: float = 0.01
    """A retreat cut short is kept if it leaves the handle at least this far beyond the fingertips, m."""
    refine_tolerance: float = 0.002
    """A waypoint is added where the grasp point between two IK waypoints strays this far from the path, m."""
    refine_passes: int = 3
    """Rounds of adding such waypoints."""
    max_base_stops: int = 3
    """Most base stops tried (1, 2, ... until base placement succeeds)."""
    track_position_tolerance: float = 0.005
    """Largest IK residual accepted along the handle path, m."""
    track_orientation_tolerance: float = float(np.deg2rad(3.0))
    """Largest IK orientation residual accepted along the handle path, rad."""
    gripper_time: float = 0.5
    """Duration of opening or closing the gripper, s."""
    grasp_settle_time: float = 0.3
    """Pause after closing and after opening the gripper, s."""
    release_hold_time: float = 1.5
    """Pause holding the handle at the target before opening the gripper (the part comes to rest), s. The true
    scenes' parts glide (damping 1 N s/m, no friction: a 9.4 kg drawer let go at 8 mm/s runs on for 9 s), so a
    part let go still moving ends short. Stretch 3's telescope (four stages tied by soft equalities) lags its
    leading stage by up to 3 cm while pulling and swings back after the stop: at 0.8 s the drawer of
    person_partial_pri_drawer_00 (twin plan, true scene) was let go at 8 mm/s and ended 2.55 cm short, at 1.5 s
    it rests within 4 mm of the target."""
    free_range_step: float = float(np.deg2rad(0.5))
    """Step of the scan for where a revolute part first runs into the rest of the scene ('open' and 'close'
    stop ``end_margin`` short of it as of a joint stop), rad."""
    free_range_step_m: float = 0.002
    """The same step for prismatic parts, m."""
    demo_min_step_rad: float = float(np.deg2rad(2.0))
    """Demonstrated states closer than this to the previous kept one are dropped from the path, rad."""
    demo_min_step_m: float = 0.01
    """The same for prismatic parts, m."""
    time_budget: float = 10.0
    """Planning stops trying further grasp tilts and base stops after this much CPU time, s (CPU, not wall
    time: on a loaded machine a wall-clock budget cut attempts and the same plan failed or passed by load)."""
    time_limit: float = 30.0
    """Hard CPU-time limit of the whole plan, s: every stage (handle path, base placement, whole-body IK, timing)
    checks it and the plan fails, naming the stage, once it is spent (``time_budget`` only stops new attempts;
    the largest plans of the robot bench take under 7 s)."""
    settle_time: float = 1.0
    """Longest simulated time over which the planner lets the part come to rest in the scene before planning
    from it (``feasibility.resting_state``; gt18's one such part, a door pushed out of the counter, rests in
    0.4 s), s."""
    settle_speed: float = 1e-3
    """The part is at rest once it moves slower than this, rad/s or m/s."""
    settle_tolerance_rad: float = float(np.deg2rad(0.5))
    """A revolute part that comes to rest further than this from its recorded state is planned from where it
    rests, rad: 0.5 deg moves a handle 0.35 m from the hinge by 3 mm, within the IK's 5 mm."""
    settle_tolerance_m: float = 0.002
    """The same for a prismatic part, m."""
    footprint_radius: float = 2.5
    """Furniture within this distance of the handle path enters base placement, m."""
    falling_retreat_scale: float = 0.2
    """Speed of the retreat from a part let go to fall open (a drop-down door beyond the arm's reach), as a
    fraction of the usual: it rests on a finger until the hand has slid off the bar along it."""
    fall_sweep_margin: float = float(np.deg2rad(15.0))
    """The base keeps clear of a part let go to fall over this much beyond the state it is expected to come to
    rest at (a twin's range is the demonstrated one; the real stop may lie further), rad."""
    fall_ignores_friction: bool = True
    """Whether a part let go where the arm's reach ends falls on is judged on gravity alone, not against its joint's
    friction: a twin's friction is no measurement (funrec's export sets it to 1.5 times the largest gravity load
    over the range, ``ExportConfig.friction_gravity_margin``, so that the twin holds a part where it is put), so on
    a twin no drop-down door would fall, and plans on the r16 twins let the dishwasher's and oven's doors go as if
    held; in their true scenes they fell to their stops, 0.5 rad beyond the planned target. The plan then keeps
    the base clear of the fall and turns the fingers off the bar whatever the friction; a door that friction does
    hold stays where it was let go, short of the plan's target."""
    path_cut_fraction: float = 0.8
    """'open' / 'close' of a part that does not fall on: where the whole-body IK follows the handle over this fraction
    of the way and then loses it, the target is cut to short of there (``plan._search_or_cut``), as where the arm's
    reach ends."""
    path_cut_back_rad: float = float(np.deg2rad(3.0))
    """... that far short of the first state missed, rad, so that the search's next attempts, placed for the shorter
    path, do not meet the reach's edge again."""
    path_cut_back_m: float = 0.02
    """... the same for a prismatic part, m."""
    fall_rest_force: float = 20.0
    """Such a part is let go no further than where its weight presses on the finger it rests on with this
    force, N (nor further than the arm holds, ``feasibility.hand_capacity``): the hand then slides off the bar
    against as much friction again (mu ~ 1), so the handle sees up to twice this; 20 N keeps that a fifth below
    the handle force bound (50 N), for the shakes of the opening jaws and of the fall. At 25 N Fetch met 50.8 and
    50.3 N sliding off two dishwasher doors (light_harsh_rev_dishwasher_00, plain_rev_dishwasher_00_r1); at 20 N
    40-41 N."""


__all__ = ["PlanConfig"]
