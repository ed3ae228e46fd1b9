"""reconstruct(): the only place that knows the order of the stages.

capture -> camera trajectory -> scene change -> static/dynamic fragments -> point tracks and
articulation per dynamic fragment -> one part per interacted part (a part opened twice merged)
-> part motion -> part masks -> TSDF meshes -> gravity -> hands and affordances -> twin folder
(FORMATS.md section 2, plus fragments.json).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import trimesh
from threadpoolctl import threadpool_limits  # a dependency of scikit-learn

from funrec.affordance.contacts import AffordanceConfig, find_affordances
from funrec.camera.intrinsics_consistency import IntrinsicsCheckConfig, require_consistent_intrinsics
from funrec.camera.tracking import CameraTrajectory, TrackingConfig, track_camera
from funrec.export.simulation import ExportConfig, InMemoryTwin, export_simulation
from funrec.export.twin import TwinWriter
from funrec.formats.affordances import TWIN_HAND_MASKS, write_affordances
from funrec.formats.capture import Capture, load_capture
from funrec.formats.fragments import Fragment, Fragments, write_fragments
from funrec.formats.meshes import as_written
from funrec.formats.staged_folder import refuse_output_over_input
from funrec.formats.twin import ArticulatedPart, TwinArticulation, make_part
from funrec.formats.twin_config import TWIN_CONFIG_FILE, write_twin_config
from funrec.formats.twin_gravity import TWIN_GRAVITY_FILE, TwinGravity, write_twin_gravity
from funrec.geometry.transforms import transform_points
from funrec.parts.articulation import (
    ArticulationConfig,
    InteractionEvidence,
    PartEstimate,
    estimate_articulation,
    fit_part,
)
from funrec.parts.camera_lock import CameraLockConfig, lock_correction, unlock_camera
from funrec.parts.depth_proposal import DepthProposal, DepthProposalConfig, proposal_tracks, propose_part, tracks_refute
from funrec.parts.fragment_tracks import WindowTracks, join_windows, sub_capture, sub_trajectory, track_window
from funrec.parts.fragments import FragmentConfig, find_fragments, fragments_from_spans, motion_span
from funrec.parts.joint_type import JointTypeConfig, choose_joint_type
from funrec.parts.part_merge import PartMergeConfig, canonical_part_points, merge_parts
from funrec.parts.part_motion import PartMotion, PartMotionConfig, refine_part_motion
from funrec.parts.point_tracks import PointTrackConfig, PointTracks
from funrec.parts.scene_change import SceneChangeConfig, scene_change
from funrec.surfaces.fusion import FusionConfig, fuse_tsdf
from funrec.surfaces.gravity import GravityConfig, estimate_gravity
from funrec.surfaces.hands import detect_hands, write_hand_masks
from funrec.surfaces.segmentation import PartMasks, SegmentationConfig, segment_parts
from funrec.typed import FloatArray

log = logging.getLogger(__name__)

StageProgress = Callable[[str, int, int], None]
"""progress(stage, done, total): called as each stage advances."""


@dataclass(frozen=True)
class ReconstructConfig:
    """Settings of the whole reconstruction; each stage has its own config."""

    intrinsics_check: IntrinsicsCheckConfig = field(default_factory=IntrinsicsCheckConfig)
    """The video checked against intrinsics.json before anything else (a capture it disagrees with is refused)."""
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    """Camera tracking (stage 1)."""
    point_tracks: PointTrackConfig = field(default_factory=PointTrackConfig)
    """Sparse 3D point tracks (stage 2) of each dynamic fragment with its context."""
    scene_change: SceneChangeConfig = field(default_factory=SceneChangeConfig)
    """Scene change unexplained by the camera (evidence of interactions)."""
    fragments: FragmentConfig = field(default_factory=FragmentConfig)
    """Static and dynamic fragments of the video."""
    articulation: ArticulationConfig = field(default_factory=ArticulationConfig)
    """Articulation-aware motion clustering (stage 3), run on each dynamic fragment."""
    depth_proposal: DepthProposalConfig = field(default_factory=DepthProposalConfig)
    """A part proposed from depth alone where the tracks give none (plain fronts)."""
    joint_type: JointTypeConfig = field(default_factory=JointTypeConfig)
    """The joint type of each found part decided in depth when the tracks cannot tell."""
    camera_lock: CameraLockConfig = field(default_factory=CameraLockConfig)
    """When the camera trajectory followed a found part instead of the static scene (undone)."""
    part_merge: PartMergeConfig = field(default_factory=PartMergeConfig)
    """When parts of two fragments are one part (opened twice)."""
    part_motion: PartMotionConfig = field(default_factory=PartMotionConfig)
    """Joint optimisation of part poses and articulation (stage 5)."""
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    """Part masks (stage 4)."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    """TSDF fusion (stage 6)."""
    export: ExportConfig = field(default_factory=ExportConfig)
    """Simulation exports (twin.urdf, twin.xml, twin.usda)."""
    gravity: GravityConfig = field(default_factory=GravityConfig)
    """Gravity alignment of the twin's world frame."""
    affordances: AffordanceConfig = field(default_factory=AffordanceConfig)
    """Hand-contact affordances (affordances.json)."""
    align_gravity: bool = True
    """Express the twin in a gravity-aligned frame (z up, origin on the floor below camera 0);
    off: the world is camera 0's frame."""
    use_hand_masks: bool = True
    """Use the capture's hand masks when it has them (off: behave as if it had none)."""
    hands_first: bool = True
    """Without hand masks in the capture, detect hands and arms once the fragments are known
    (:func:`~funrec.surfaces.hands.detect_hands` without parts) and feed them to point tracks,
    articulation, depth proposals, part motion and masks as capture masks are fed: a rigid
    textured arm is otherwise the most trackable moving thing in the video, and its tracks become
    a part. Detected again with the parts known for fusion and affordances. Off: ablation."""
    hand_recheck_fraction: float = 0.25
    """Hands-first masks label a depth proposal's own part when more than this fraction of the part's
    points that the depth sees in place fall inside the hand mask (in ``hand_recheck_frames`` frames);
    hands are then detected again in the span with the proposal's motion known and the proposal made
    again. Right masks label ~0 (a hand in front of the part hides its points); on plain_rev_oven_00
    the door swinging towards the camera was labelled hand over nearly all of it in 10+ frames."""
    hand_recheck_frames: int = 3
    """... in at least this many frames (one or two frames of a badly placed proposal do not count)."""
    use_object_masks: bool = True
    """Use the capture's interacted-object masks when it has them."""
    align_fragments: bool = True
    """When the video has more than one fragment, register the fragments' static submaps and
    correct the camera trajectory per fragment (:func:`funrec.camera.global_alignment.align_fragments`,
    default settings) before the dynamic fragments are tracked; a correction is kept only where it
    fits better than the tracker's poses (measured on multi_kitchen_00, multi_same_00 and
    rev_cabinet_left_00 of the synthetic bench: no camera moved by more than 0.4 mm); off: the
    camera tracker's trajectory as it is."""
    fragment_context_s: float = 1.5
    """Articulation of a dynamic fragment sees its tracks this long before and after it (never
    into another dynamic fragment), seconds: the part at rest on both sides anchors its joint."""
    parts_per_fragment: int = 1
    """Parts kept per dynamic fragment, best interaction score first: one interaction moves one
    part, and further clusters of a fragment are usually the hand or drift."""
    blas_threads: int = 1
    """Threads of the BLAS libraries (numpy and scipy matrix products) while reconstructing; 0
    keeps the library default (one per core). The products here are small or thin (n x 3, n x 4):
    extra BLAS threads only spin and wait, on a shared machine for their turn. One thread cut the
    CPU time of the synthetic bench's pri_wardrobe_00 by 12 % (articulation 8.7 -> 5.3 s, part
    motion 2.2 -> 1.3 s; measured)."""


@dataclass(frozen=True)
class PartSummary:
    """What was found for one part."""

    name: str
    joint_type: str
    """"revolute" or "prismatic"."""
    state_range: tuple[float, float]
    """Observed joint interval, rad or m."""
    frames: tuple[int, int]
    """First and last tracked frame."""


@dataclass(frozen=True)
class ReconstructionSummary:
    """Outcome of :func:`reconstruct`."""

    twin_dir: Path
    """The written twin folder."""
    frame_count: int
    """Frames in the capture."""
    parts: tuple[PartSummary, ...]
    """Parts found (empty: nothing was opened)."""
    fragments: tuple[Fragment, ...]
    """Static and dynamic fragments of the video, in time order (fragments.json)."""
    stage_seconds: dict[str, float]
    """Wall time of each stage, seconds."""
    untracked_frames: int
    """Frames whose camera pose was interpolated rather than registered."""
    stage_cpu_seconds: dict[str, float] = field(default_factory=dict)
    """CPU time (user + system, all threads of the process) of each stage, seconds: on a shared
    machine the measure of a stage's cost that other processes do not inflate."""


def _articulated(name: str, motion: PartMotion, T_twin_world: FloatArray, mesh: str | None = None,
                 masks: str | None = None) -> ArticulatedPart:
    """The part of ``motion`` as the twin describes it, its joint moved into the twin frame by ``T_twin_world``."""
    pivot_twin = None if motion.pivot_world is None else transform_points(T_twin_world, motion.pivot_world[None])[0]
    return make_part(name, motion.joint_type, T_twin_world[:3, :3] @ motion.axis_world, pivot_twin, motion.frames,
                     motion.states, motion.state_range, mesh=mesh, masks=masks)


def _evidence(capture: Capture, config: ReconstructConfig) -> InteractionEvidence | None:
    """Interaction evidence from the capture's masks: object masks first, then hand proximity."""
    confidence = np.ones(len(capture))
    if capture.has_object_masks and config.use_object_masks:
        return InteractionEvidence.from_masks(lambda frame: capture.mask("object", frame), confidence)
    if capture.has_hand_masks and config.use_hand_masks:
        return InteractionEvidence.from_hand_masks(lambda frame: capture.mask("hand", frame), confidence)
    return None


def _hands_first(capture: Capture, trajectory: CameraTrajectory, folder: Path, config: ReconstructConfig,
                 progress: Callable[[int, int], None] | None) -> Capture:
    """The capture with hand masks detected before any part is known, written to ``folder`` (the
    twin's masks/hand, replaced later by the detection that knows the parts)."""
    hands = detect_hands(capture, trajectory, (), (), config.affordances.hands, progress=progress)
    write_hand_masks(folder, hands)
    paths = tuple(folder / f"{frame:06d}.png" for frame in range(len(capture)))
    return dataclasses.replace(capture, mask_paths={**capture.mask_paths, "hand": paths})


def _hand_visible(capture: Capture) -> npt.NDArray[np.bool_] | None:
    """(F,) True where the capture's hand mask is non-empty; None without hand masks."""
    if not capture.has_hand_masks:
        return None
    return np.array([bool(mask is not None and mask.any()) for mask in (capture.mask("hand", i) for i in range(len(capture)))])


def _window(fragments: Fragments, k: int, context: int) -> tuple[int, int]:
    """Inclusive frames the articulation of dynamic fragment k sees: the fragment and ``context``
    frames on each side, stopping short of the neighbouring dynamic fragments."""
    dynamic = fragments.dynamic
    first = max(dynamic[k].first - context, dynamic[k - 1].last + 1 if k > 0 else 0)
    last = min(dynamic[k].last + context, dynamic[k + 1].first - 1 if k + 1 < len(dynamic) else fragments.frame_count - 1)
    return first, last


def _window_evidence(evidence: InteractionEvidence | None, window: WindowTracks) -> InteractionEvidence | None:
    """The interaction evidence of a window's frames, indexed from the window's first frame."""
    if evidence is None:
        return None
    first = window.first
    return InteractionEvidence(lambda frame, uv: evidence.lookup(frame + first, uv), evidence.confidence[first : window.last + 1],
                               evidence.kind)


def _motion_scene_change(part: PartEstimate, first: int, change: npt.NDArray[np.float64]) -> float:
    """Scene change while the part moves: the capture's per-pair scene change averaged over the
    part's frames, weighted by its state step there. Without masks, the arm reaching in and out
    fits a joint too; the interacted part is the one that moves while the scene changes most."""
    steps = np.abs(np.diff(part.states))
    total = float(steps.sum())
    return float(steps @ change[part.frames[:-1] + first]) / total if total > 0.0 else 0.0


@dataclass(frozen=True)
class FragmentParts:
    """Stage 3's outcome on the dynamic fragments."""

    found: list[tuple[int, PartEstimate]]
    """(fragment index, part) of each part kept; frames and track indices local to the window."""
    reasons: dict[int, str]
    """Why no part was built, for each dynamic fragment index that has none."""
    windows: list[WindowTracks]
    """The windows' tracks, with the tracks of parts proposed from depth appended."""
    from_depth: frozenset[int] = frozenset()
    """Fragment indices whose part was proposed from depth, or whose tracks' joint type depth's best
    hypothesis shares: the type already won against every other hypothesis in depth, so the
    joint-type stage leaves it alone."""


def _fragment_parts(windows: list[WindowTracks], evidence: InteractionEvidence | None, config: ReconstructConfig,
                    change: npt.NDArray[np.float64] | None = None, capture: Capture | None = None,
                    trajectory: CameraTrajectory | None = None, hands_detected: bool = False,
                    dynamic_first: Sequence[int] = ()) -> FragmentParts:
    """Stage 3 on each dynamic fragment's tracks: the best ``parts_per_fragment`` parts of each.
    Without mask ``evidence``, the parts are ranked by size x scene change while they move
    (``change``, (F,) per frame pair of the capture; :func:`_motion_scene_change`). Where the
    tracks give no part (a plain front), one is proposed from the ``capture``'s depth
    (:func:`~funrec.parts.depth_proposal.propose_part`) and its tracks join the window's; the window's frames
    before its dynamic fragment's first frame (``dynamic_first[k]``, capture frames) show that part at rest."""
    found, reasons, windows, from_depth = [], {}, list(windows), set()
    for k, window in enumerate(windows):
        parts = list(estimate_articulation(window.tracks, _window_evidence(evidence, window), config.articulation).parts)
        if evidence is None and change is not None:
            parts.sort(key=lambda p: -p.size_score * _motion_scene_change(p, window.first, change))
        if (not parts or _challenge(capture, config)) and capture is not None and trajectory is not None:
            rest = dynamic_first[k] - window.first if k < len(dynamic_first) else 0
            proposed = _depth_part(window, capture, trajectory, config, parts[0] if parts else None, hands_detected, rest)
            if proposed is not None:
                if parts:
                    log.info("fragment %d: depth's %s replaces the tracks' %s", k, proposed[1].joint_type,
                             parts[0].joint_type)
                windows[k], part = proposed
                parts = [part]
                from_depth.add(k)
        found += [(k, part) for part in parts[: config.parts_per_fragment]]
        if not parts:
            reasons[k] = (f"no moving part fitted the {window.tracks.num_tracks} point tracks of frames "
                          f"{window.first}-{window.last}"
                          + (", and depth showed no surface that left as a joint moves it" if config.depth_proposal.enabled
                             else ""))
        log.info("fragment %d (window %d-%d): %s", k, window.first, window.last,
                 ", ".join(p.joint_type for p in parts[: config.parts_per_fragment]) or reasons[k])
    return FragmentParts(found, reasons, windows, frozenset(from_depth))


def _challenge(capture: Capture | None, config: ReconstructConfig) -> bool:
    """Whether depth may replace a part the tracks found: only where no object masks say which
    surface is the part (hand masks say where the hand was, not how the part moved)."""
    masked = capture is not None and capture.has_object_masks and config.use_object_masks
    return config.depth_proposal.challenge and not masked


def _depth_part(window: WindowTracks, capture: Capture, trajectory: CameraTrajectory, config: ReconstructConfig,
                rival: PartEstimate | None = None, hands_detected: bool = False,
                rest_frames: int = 0) -> tuple[WindowTracks, PartEstimate] | None:
    """A part proposed from the window's depth: the window with the part's tracks appended, and
    the part fitted to them (frames and track indices local to the window). Where the ``rival``
    (the tracks' part) is a slide and depth's best hypothesis is a slide too, the rival's slide on
    depth's surface. None when depth proposes nothing, or the rival holds. With ``hands_detected``
    (the capture's hand masks came from the hands-first detection), a proposal whose own surface
    they label hand is made again with hands detected knowing its motion. The window's first ``rest_frames``
    frames come before the scene changed (see :func:`~funrec.parts.depth_proposal.propose_part`)."""
    span, poses = sub_capture(capture, window.first, window.last), sub_trajectory(trajectory, window.first, window.last)
    if rival is not None and lock_correction(rival, poses.T_world_camera, config.camera_lock) is not None:
        # the camera followed the tracks' part: it is the static scene, and the camera is unlocked before the part
        # is looked for again (unlock_camera); depth's own slide on the locked poses would hide the lock
        # (mw_window_00: the lock went unseen, camera ATE 28.8 cm, the window lost)
        return None
    hand = (lambda frame: span.mask("hand", frame)) if span.has_hand_masks else None
    joint = None if rival is None else (rival.joint_type, rival.axis_world, rival.pivot_world)
    seen = None if rival is None else (rival.frames[~rival.interpolated], rival.states[~rival.interpolated])
    proposal = propose_part(span, poses, hand, config.depth_proposal, joint, seen, rest_frames)
    added = proposal_tracks(proposal, span, poses) if proposal is not None and hands_detected else None
    if added is not None and _hand_labels_part(added, span, config):
        # hands detected before any part was known take a part moving towards the camera for the arm (a
        # drop-down oven door: plain_rev_oven_00 axis 9.4 deg off, range 107 deg for 74): detected again with
        # the proposed part's motion known, its pixels are explained by it and stay in the depth
        hands = detect_hands(span, poses, (_proposed_part(proposal),), (),
                             dataclasses.replace(config.affordances.hands, use_capture_masks=False))
        log.info("depth proposal: hands detected again in frames %d-%d with the proposed %s known",
                 window.first, window.last, proposal.joint_type)
        first = proposal
        # without the tracks' joint, the first proposal's joint is the rival: the masks detected again must not
        # lose a joint that explains the surface as well (dark_rev_glass_wall_00: the first proposal's hinge,
        # 0.4 deg, range 1.53 rad for 1.57, was replaced by one 41 deg off)
        again = joint if joint is not None else (first.joint_type, first.axis_world, first.pivot_world)
        proposal = propose_part(span, poses, lambda frame: hands.mask(frame), config.depth_proposal, again, seen,
                                rest_frames)
        if joint is None and proposal is not None and proposal.rival_held:
            log.info("depth proposal: the first proposal's %s holds against the one made with the hands detected again",
                     first.joint_type)
            proposal = first
        added = None
    if proposal is None:
        return None
    if proposal.rival_held and (rival is None or proposal.joint_type != rival.joint_type or proposal.joint_type == "revolute"):
        return None
    if rival is not None and tracks_refute(proposal, rival, window.tracks, config.depth_proposal):
        return None
    # depth's part replaces the tracks' part: its joint explains the surface that left clearly better, or it is
    # the tracks' own slide on that surface (see propose_part)
    if added is None:
        added = proposal_tracks(proposal, span, poses)
    N = window.tracks.num_tracks
    tracks = PointTracks(np.concatenate([window.tracks.p_world, added.p_world], 1),
                         np.concatenate([window.tracks.uv, added.uv], 1),
                         np.concatenate([window.tracks.visible, added.visible], 1))
    part = fit_part(tracks, np.arange(N, N + added.num_tracks), proposal.joint_type, config.articulation,
                    size_score=float(added.num_tracks))
    if part is None:
        return None
    return WindowTracks(window.first, window.last, tracks), part


def _hand_labels_part(tracks: PointTracks, span: Capture, config: ReconstructConfig) -> bool:
    """Whether the span's hand masks label the proposed part itself, given the proposal's ``tracks``
    (:func:`~funrec.parts.depth_proposal.proposal_tracks`: its points where the joint puts them,
    visible where the depth sees them there): in at least ``hand_recheck_frames`` frames, more than
    ``hand_recheck_fraction`` of the visible points fall inside the hand mask. A hand in front of
    the part hides its points (the depth there is nearer), so right masks give ~0 (mask edges only)."""
    labelled = 0
    for frame in range(len(span)):
        mask = span.mask("hand", frame)
        seen = np.flatnonzero(tracks.visible[frame])
        if mask is None or len(seen) < config.depth_proposal.min_points:
            continue
        uv = np.rint(tracks.uv[frame, seen]).astype(int)
        if mask[uv[:, 1], uv[:, 0]].mean() > config.hand_recheck_fraction:
            labelled += 1
    return labelled >= config.hand_recheck_frames


def _proposed_part(proposal: DepthProposal) -> ArticulatedPart:
    """The proposal as an articulated part over its span's frames (for the hand detector)."""
    frames = np.arange(len(proposal.states))
    return make_part("proposed", proposal.joint_type, proposal.axis_world, proposal.pivot_world, frames,
                     proposal.states, (float(proposal.states.min()), float(proposal.states.max())))


def _part_span(windows: list[WindowTracks], found: list[tuple[int, PartEstimate]], owner: list[int], index: int,
               estimate: PartEstimate) -> tuple[WindowTracks, PartEstimate]:
    """The tracks of every fragment merged part ``index`` was seen in, joined over its span, and
    its (merged, capture-frame) estimate with frames and track indices local to that span."""
    members = [i for i, o in enumerate(owner) if o == index]
    window_ids = sorted({found[i][0] for i in members})
    span, offsets = join_windows([windows[w] for w in window_ids])
    offset = dict(zip(window_ids, offsets, strict=True))
    tracks = np.unique(np.concatenate([offset[found[i][0]] + found[i][1].track_indices for i in members]))
    return span, dataclasses.replace(estimate, frames=estimate.frames - span.first, track_indices=tracks)


def _final_fragments(fragments: Fragments, windows: list[WindowTracks], found: list[int], owner: list[int],
                     part_states: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]], config: ReconstructConfig,
                     arm_in_evidence: bool = True, reasons: dict[int, str] | None = None) -> Fragments:
    """The fragments once parts are known: each dynamic fragment in which a part was found is
    trimmed to that part's motion inside the fragment's window where its states show it
    (:func:`~funrec.parts.fragments.motion_span`) and names the part; one in which no part was found
    stays dynamic, names no part and says why (``reasons``): scene change is never silently static. Trimming, and a side the states miss taken from the
    scene change of the part's motion, happen only with ``arm_in_evidence`` (no hand masks: the
    scene change also shows the arm reaching in and out); with hand masks the hand-gated scene
    change already spans the interaction, which goes on while the hand holds the part still.

    Args:
        fragments: the detected fragments.
        windows: the tracked window of each dynamic fragment.
        found: per part found, the index of its dynamic fragment.
        owner: per part found, the index of the merged part it belongs to.
        part_states: per merged part, its (F_m,) capture frames and (F_m,) states.
        config: settings.
        arm_in_evidence: the fragments' scene change includes the arm (no hand masks).
        reasons: why no part was built, per dynamic fragment index without one.
    """
    spans: list[tuple[int, int, str | None, str | None]] = []
    for k, fragment in enumerate(fragments.dynamic):
        if k not in found:
            spans.append((fragment.first, fragment.last, None, (reasons or {}).get(k, "no part was found in it")))
    for k, merged_index in zip(found, owner, strict=True):
        first, last = fragments.dynamic[k].first, fragments.dynamic[k].last
        frames, states = part_states[merged_index]
        inside = (frames >= windows[k].first) & (frames <= windows[k].last)
        start, stop = None, None
        if arm_in_evidence:
            start, stop = motion_span(frames[inside], states[inside], fragments.fps, config.fragments, fragments.evidence,
                                      config.scene_change.lag_frames)
        first, last = max(first, start if start is not None else first), min(last, stop if stop is not None else last)
        if first <= last:
            spans.append((first, last, f"part_{merged_index}", None))
    spans.sort(key=lambda s: s[:2])  # detected fragments are disjoint, and trimming only shrinks them
    tiles = fragments_from_spans([(a, b) for a, b, _, _ in spans], fragments.frame_count, [s[2] for s in spans],
                                 [s[3] for s in spans])
    return dataclasses.replace(fragments, fragments=tiles)


def _rename_parts(fragments: Fragments, names: dict[str, str]) -> Fragments:
    """The fragments with their part names mapped by ``names``; a part not in it was dropped (its
    fragment stays dynamic, names no part and says so)."""
    renamed = tuple(
        dataclasses.replace(f, part=names[f.part]) if f.part in names
        else dataclasses.replace(f, part=None, reason=f"{f.part} was found but fused into no surface (empty masks): dropped")
        if f.part is not None else f
        for f in fragments.fragments
    )
    return dataclasses.replace(fragments, fragments=renamed)


def reconstruct(
    capture_dir: str | Path,
    out_dir: str | Path,
    config: ReconstructConfig = ReconstructConfig(),  # noqa: B008 (frozen, immutable default)
    progress: StageProgress | None = None,
    overwrite: bool = False,
) -> ReconstructionSummary:
    """Reconstruct a functional twin from a capture folder and write the twin folder.

    Args:
        capture_dir: capture folder (FORMATS.md section 1).
        out_dir: twin folder to write; written to a temporary sibling and renamed into place.
        config: stage settings.
        progress: optional ``progress(stage, done, total)``.
        overwrite: replace an existing non-empty ``out_dir``.

    Raises:
        CaptureError: the capture is malformed (names file and frame).
        ReconstructionError: the capture cannot be reconstructed (says why).
        FunrecError: ``out_dir`` is, contains or lies inside ``capture_dir``.
    """
    refuse_output_over_input(out_dir, capture_dir)
    if config.blas_threads <= 0:
        return _reconstruct(capture_dir, out_dir, config, progress, overwrite)
    with threadpool_limits(limits=config.blas_threads, user_api="blas"):
        return _reconstruct(capture_dir, out_dir, config, progress, overwrite)


def _reconstruct(capture_dir: str | Path, out_dir: str | Path, config: ReconstructConfig, progress: StageProgress | None,
                 overwrite: bool) -> ReconstructionSummary:
    """:func:`reconstruct` under its BLAS thread limit."""
    capture = load_capture(capture_dir)
    if not config.use_hand_masks or not config.use_object_masks:
        kept = {k: v for k, v in capture.mask_paths.items() if (k != "hand" or config.use_hand_masks) and (k != "object" or config.use_object_masks)}
        capture = dataclasses.replace(capture, mask_paths=kept)
    seconds: dict[str, float] = {}
    cpu_seconds: dict[str, float] = {}

    def stage_progress(name: str) -> Callable[[int, int], None] | None:
        if progress is None:
            return None
        return lambda done, total: progress(name, done, total)

    def timed(name: str, fn, *args, **kwargs):  # noqa: ANN001, ANN202 (thin timing wrapper)
        start, start_cpu = time.perf_counter(), time.process_time()
        # A stage without progress of its own is still named while it runs (export takes a third
        # of a run; its time was shown under the stage before it).
        silent = progress is not None and "progress" not in kwargs
        if silent:
            progress(name, 0, 1)
        result = fn(*args, **kwargs)
        if silent:
            progress(name, 1, 1)
        seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - start
        cpu_seconds[name] = cpu_seconds.get(name, 0.0) + time.process_time() - start_cpu
        log.info("%s: %.1f s (CPU %.1f s)", name, seconds[name], cpu_seconds[name])
        return result

    timed("intrinsics", require_consistent_intrinsics, capture, config.intrinsics_check)  # before anything is written
    with TwinWriter(out_dir, overwrite=overwrite) as writer:
        trajectory = timed("camera", track_camera, capture, config.tracking, progress=stage_progress("camera"))
        change = timed("scene change", scene_change, capture, trajectory.T_world_camera, config.scene_change,
                       progress=stage_progress("scene change"))
        fragments = find_fragments(change, capture.intrinsics.fps, config.scene_change.lag_frames, _hand_visible(capture),
                                   config.fragments)
        if config.align_fragments and len(fragments.fragments) > 1:
            from funrec.camera.global_alignment import align_fragments  # optional stage: imported only when on

            intervals = [(f.first, f.last) for f in fragments.fragments]
            alignment = timed("alignment", align_fragments, capture, trajectory, intervals, progress=stage_progress("alignment"))
            trajectory = alignment.trajectory
        # Hands first (no hand masks recorded): detected before any part is known, they keep the arm out of the
        # tracks, the articulation and the depth proposals. Not out of scene change and fragments: without the
        # parts, the detector also takes the moving door for the arm (measured on plain_rev_cabinet_right_00: the
        # scene-change peak fell from 0.085 to 0.009 and the interaction was lost).
        observed = capture  # as recorded: the final hand detection knows the parts
        if config.hands_first and not capture.has_hand_masks:
            capture = timed("hands first", _hands_first, capture, trajectory, writer.path(TWIN_HAND_MASKS), config,
                            stage_progress("hands first"))
        context = int(round(config.fragment_context_s * capture.intrinsics.fps))
        windows = [
            timed("tracks", track_window, capture, trajectory, *_window(fragments, k, context), config.point_tracks,
                  progress=stage_progress(f"tracks fragment {k}"))
            for k in range(len(fragments.dynamic))
        ]
        dynamic_first = [fragment.first for fragment in fragments.dynamic]
        outcome = timed("articulation", _fragment_parts, windows, _evidence(capture, config), config, change, capture,
                        trajectory, capture is not observed, dynamic_first)
        unlocked = unlock_camera(trajectory, outcome.windows, outcome.found, config.camera_lock)
        if unlocked is not None:  # the camera had followed a part: poses and tracks corrected, parts found again
            trajectory, windows = unlocked
            outcome = timed("articulation", _fragment_parts, windows, _evidence(capture, config), config, change, capture,
                            trajectory, capture is not observed, dynamic_first)
        windows = outcome.windows
        # a part proposed from depth already beat the other joint type there (with the surfaces that
        # arrived in front): the tracks-based check would overturn it on its own points alone (measured on
        # mw_door_00: the proposal's hinge, cost 0.527 against 1.440 still, turned into a wrong slide)
        found = [(k, part if k in outcome.from_depth else
                  timed("joint type", choose_joint_type, part, windows[k].tracks,
                        sub_capture(capture, windows[k].first, windows[k].last),
                        sub_trajectory(trajectory, windows[k].first, windows[k].last), config.articulation,
                        config.joint_type))
                 for k, part in outcome.found]
        in_capture = [dataclasses.replace(part, frames=part.frames + windows[k].first) for k, part in found]
        points = [canonical_part_points(part, windows[k].tracks) for k, part in found]
        estimates, owner = timed("part merge", merge_parts, in_capture, points, config.part_merge)
        motions: list[PartMotion] = []
        all_masks: list[PartMasks] = []
        for k, estimate in enumerate(estimates):
            # each part on the frames of its fragments' tracks: frames local to that span
            span, local = _part_span(windows, found, owner, k, estimate)
            span_capture, span_trajectory = sub_capture(capture, span.first, span.last), sub_trajectory(trajectory, span.first, span.last)
            motion = timed("part motion", refine_part_motion, span.tracks, local, config.part_motion,
                           capture=span_capture, trajectory=span_trajectory)
            moving = np.zeros(span.tracks.num_tracks, dtype=bool)
            moving[local.track_indices] = True
            masks = timed("masks", segment_parts, span_capture, span_trajectory, span.tracks, moving, motion.frames,
                          motion.T_world_part, config.segmentation, progress=stage_progress(f"masks part_{k}"))
            motions.append(dataclasses.replace(motion, frames=motion.frames + span.first, edge_frames=motion.edge_frames + span.first))
            all_masks.append(dataclasses.replace(masks, frames=masks.frames + span.first, keyframes=masks.keyframes + span.first))
        fragments = _final_fragments(fragments, windows, [k for k, _ in found], owner,
                                     [(m.frames, m.states) for m in motions], config, not observed.has_hand_masks,
                                     outcome.reasons)
        # Hands before fusion, so that detected hands and arms (no masks in the capture) stay out of the static
        # scene as masked ones do; image-space masks, unchanged by the gravity alignment that follows.
        moved = [_articulated(f"part_{k}", motion, np.eye(4)) for k, motion in enumerate(motions)]
        hands = timed("hands", detect_hands, observed, trajectory, moved, all_masks, config.affordances.hands,
                      progress=stage_progress("hands"))
        meshes = timed(
            "fusion",
            fuse_tsdf,
            capture,
            trajectory,
            all_masks,
            [m.T_world_part for m in motions],
            config.fusion,
            progress=stage_progress("fusion"),
            hands=hands,
        )
        T_twin_world = np.eye(4)
        if config.align_gravity:
            alignment = timed("gravity", estimate_gravity, meshes.static.vertices, trajectory.T_world_camera, config.gravity)
            T_twin_world = alignment.T_aligned_world
            write_twin_gravity(writer.path(TWIN_GRAVITY_FILE), TwinGravity(alignment.source, alignment.floor))
        written: dict[str, trimesh.Trimesh] = {}  # what the PLY files hold, handed to the export

        def write_mesh(mesh: trimesh.Trimesh, relative: str) -> trimesh.Trimesh:
            mesh.export(writer.path(relative))
            written[relative] = as_written(mesh)
            return mesh

        write_mesh(meshes.static.copy().apply_transform(T_twin_world), "meshes/static.ply")
        # A part whose masks fused into no surface cannot be scored or simulated: dropped.
        kept = [k for k, mesh in enumerate(meshes.parts) if k not in meshes.empty_parts and len(mesh.faces) > 0]
        if len(kept) < len(motions):
            log.warning("%d of %d parts have no mesh and are dropped", len(motions) - len(kept), len(motions))
        fragments = _rename_parts(fragments, {f"part_{old}": f"part_{new}" for new, old in enumerate(kept)})
        motions, all_masks = [motions[k] for k in kept], [all_masks[k] for k in kept]
        parts, surfaces = [], []
        for k, (motion, mesh, masks) in enumerate(zip(motions, [meshes.parts[k] for k in kept], all_masks, strict=True)):
            for frame, png in zip(masks.frames, masks.png, strict=True):
                writer.path(f"masks/part_{k}/{int(frame):06d}.png").write_bytes(png)
            surfaces.append(write_mesh(mesh.copy().apply_transform(T_twin_world), f"meshes/part_{k}.ply"))
            parts.append(_articulated(f"part_{k}", motion, T_twin_world, mesh=f"meshes/part_{k}.ply", masks=f"masks/part_{k}"))
        trajectory_twin = dataclasses.replace(trajectory, T_world_camera=T_twin_world @ trajectory.T_world_camera)
        if hands.source == "detected":
            write_hand_masks(writer.path(TWIN_HAND_MASKS), hands)
        affordances = timed("affordances", find_affordances, capture, trajectory_twin, parts, surfaces, all_masks, hands,
                            config.affordances, progress=stage_progress("affordances"))
        write_affordances(writer.path("affordances.json"), affordances)
        write_fragments(writer.path("fragments.json"), fragments)
        writer.write_camera_poses(trajectory_twin.T_world_camera)
        articulation = TwinArticulation(frame_count=len(capture), parts=tuple(parts))
        writer.write_articulation(articulation)
        write_twin_config(writer.path(TWIN_CONFIG_FILE), config, capture_dir)
        timed("export", export_simulation, writer.root, config.export, InMemoryTwin(articulation, written))
    summaries = tuple(
        PartSummary(p.name, p.joint_type, p.state_range, (int(p.frames[0]), int(p.frames[-1]))) for p in parts
    )
    return ReconstructionSummary(
        twin_dir=Path(out_dir),
        frame_count=len(capture),
        parts=summaries,
        fragments=fragments.fragments,
        stage_seconds=seconds,
        untracked_frames=int((~trajectory.tracked).sum()),
        stage_cpu_seconds=cpu_seconds,
    )


__all__ = ["PartSummary", "ReconstructConfig", "ReconstructionSummary", "reconstruct"]
