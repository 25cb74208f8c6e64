"""The model contract: what a SCOTTI model sees, predicts and promises.

Everything that crosses between the simulator, training, export and the
daemon is named here once. Numpy only (ARCHITECTURE.md, room ``models/``).

Pose frame: metres, origin on the floor under the mid-hip, z up, x the way
the person faces, y to their left.
"""

from __future__ import annotations

from typing import Final

import numpy as np

# Bumped whenever a name, an order, a shape or a unit below changes; a model
# whose metadata carries another version is refused by the runtime.
CONTRACT_VERSION: Final = 2  # 2: "standing" became the ninth action

# --- Geometry of one foot frame and of the model input --------------------
FRAME_ROWS: Final = 32  # taxel rows per insole (heel at row 31, toes at row 0)
FRAME_COLS: Final = 22  # taxel columns per insole (medial side at column 0)
SAMPLE_BITS: Final = 12  # ADC resolution of one taxel
MAX_COUNT: Final = (1 << SAMPLE_BITS) - 1  # largest count the protocol allows
WINDOW: Final = 40  # T, frames in the window (2.5 s at 16 Hz)
FRAME_RATE_HZ: Final = 16.0

# --- Repair of missing input, the same live (daemon pairing) and in training --
# A silent foot's last frame is repeated this many frames (0.5 s), then zeros go in.
SILENT_FOOT_HOLD_FRAMES: Final = 8
# A gap longer than this (1 s) with no frame restarts the window: no history is invented.
WINDOW_RESTART_GAP_FRAMES: Final = 16

# --- Keypoints: COCO-WholeBody body and feet without the face (19) ---------
KEYPOINTS: Final[tuple[str, ...]] = (
    "nose",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
)
KP: Final[dict[str, int]] = {name: i for i, name in enumerate(KEYPOINTS)}
NUM_KEYPOINTS: Final = len(KEYPOINTS)

# Bones (parent, child) by keypoint name; joint angles (MPJAE) are the angles
# between each bone and its parent bone, see ``JOINT_ANGLES``.
BONES: Final[tuple[tuple[str, str], ...]] = (
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("left_ankle", "left_heel"),
    ("left_heel", "left_big_toe"),
    ("left_heel", "left_small_toe"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("right_ankle", "right_heel"),
    ("right_heel", "right_big_toe"),
    ("right_heel", "right_small_toe"),
    ("left_shoulder", "right_shoulder"),
    ("left_hip", "right_hip"),
    ("left_shoulder", "left_hip"),
    ("right_shoulder", "right_hip"),
    ("left_shoulder", "nose"),
    ("right_shoulder", "nose"),
)
BONE_INDEX: Final = np.array([[KP[a], KP[b]] for a, b in BONES], dtype=np.int64)

# Joint angles as pairs of bone indices into BONES: (upper bone, lower bone).
# Elbows, knees, ankles, the trunk-thigh (hip) angle and shoulder angle.
JOINT_ANGLES: Final[tuple[tuple[int, int], ...]] = (
    (0, 1),  # left elbow
    (2, 3),  # right elbow
    (4, 5),  # left knee
    (9, 10),  # right knee
    (5, 7),  # left ankle (shank to foot)
    (10, 12),  # right ankle
    (16, 4),  # left hip (trunk side to thigh)
    (17, 9),  # right hip
    (16, 0),  # left shoulder (trunk side to upper arm)
    (17, 2),  # right shoulder
)


# --- Actions, in the fixed order of the action head's logits --------------
# New actions are appended, so an index keeps its meaning across versions.
ACTIONS: Final[tuple[str, ...]] = (
    "squat",
    "lunge",
    "step_up",
    "jump",
    "side_walking",
    "in_place_walking",
    "backward_walking",
    "walking",
    "standing",  # weight on both feet, no repetition running (contract version 2)
)
NUM_ACTIONS: Final = len(ACTIONS)
STANDING: Final = ACTIONS.index("standing")
# Actions that run in repetitions: they have a progress indicator, a progress
# label in [0, 1] and a repetition count. Every other action (standing) has
# neither: its progress is undefined (NaN in labels, null on MQTT) and
# training leaves it out of the progress loss.
REPEATED_ACTIONS: Final[frozenset[int]] = frozenset(
    i for i, name in enumerate(ACTIONS) if name != "standing"
)
# Label value for a transition between actions (walking to a spot, the sink
# before a set of jumps): no action is named, so training leaves these frames
# out of the action and progress losses (the pose loss still uses them).
NO_ACTION: Final = -1


def has_progress(action: int) -> bool:
    """Whether frames of ``action`` (an index, or ``NO_ACTION``) have a progress label."""
    return action in REPEATED_ACTIONS


# --- The labelling convention: one for every source of labels --------------
# Script scenes and lab sessions (sim/scene.py ``build_motion``, the recipes in
# sim/actions, sim/session.py) and imported recordings (importers/labels.py) label
# the same motion the same way:
#
# - A set is one run of a repeated action's label: consecutive frames with its
#   index. The recipe of a script entry or of a lab set labels it; in an import,
#   a segment of the segment file (two segments of one action with nothing
#   between are one run).
# - Repetitions are cut where the person rests (models/progress.py): squat and
#   lunge standing tall, step-up on the floor, jump in the crouch; a repetition
#   runs from its cut to the next. Walking, walking backward and walking in place
#   run in steps, cut on the frame after a foot lands (``PeakParams.step_cut``,
#   models/touchdown.py), the values between from their indicators (heel
#   distance, minus the higher heel's height, heel displacement).
#   Side walking's repetition is its two-step cycle, cut at the heels' widest.
# - A pause between repetitions, standing at that rest, is part of the set for
#   its first ``SET_EDGE_REST_S``: it carries the set's action, progress ~0 (it
#   belongs to the repetition that follows), and the repetition just finished is
#   complete on arrival. Beyond that bound, standing straight-legged (both knees
#   bent less than ``STANDING_KNEE_FLEXION_DEG``) is ``standing`` until the next
#   movement, which starts a run of the set's action again. Every label is then
#   a function of the motion up to its frame plus at most ``SET_EDGE_REST_S``: a
#   causal model cannot tell the stillness after a set's last repetition from a
#   pause, so a pause "however long" was unanswerable after every set. A held
#   crouch is not standing and stays the set's.
# - Still standing before a set's first movement and after its last belongs to
#   the set for at most ``SET_EDGE_REST_S`` (a moment of getting ready, a hold
#   at the top; it reads ~0 like a pause); beyond that it is ``standing``
#   (models/set_edges.py applies both bounds to every source). "Still": no
#   keypoint faster than ``STILL_SPEED_MPS``. A "set" with no movement at all
#   is no set: seen and straight-legged throughout it is ``standing`` (a squat
#   of depth 0 is a person standing still); a held crouch keeps its label.
# - After the last movement of a set of ``PAUSING_ACTIONS`` the still standing is
#   the set's for exactly ``SET_EDGE_REST_S``, as a pause's is: until that second
#   is over a set's end and a pause look the same, so the label may not tell them
#   apart by what comes after. Standing straight-legged that the source labelled
#   ``standing`` is taken into the set up to the bound. The other actions' sets do
#   not pause in the simulator's recipes and end at their last movement's hold.
# - Standing: ``STANDING``, no progress (NaN), repetition -1.
# - Transitions, ``NO_ACTION``: movement that is neither a set nor standing:
#   walking to the next spot or turning round between lab sets, a jump set's
#   sink before its first crouch and rise after its last landing, and between
#   the jumps of a paused set the rise, the stand and the sink (a jump rests in
#   the crouch, so standing upright between jumps is no pause at its rest). In
#   an import: every frame in no segment. No action, no progress.
#
# The simulator's sets hold at most 0.6 s of still standing at their edges at
# tempo 1 (the recipes' lead-in and a repetition's hold at the top), so at its
# own tempo the edge bound trims none of its labels; the pause bound changes
# the pauses of squat and lunge sets longer than it (sim/actions/strength.py
# draws them up to 4.5 s), and their ends take the standing after them up to a
# second (tests/test_labelling_convention.py).
SET_EDGE_REST_S: Final = 1.0
# The actions whose sets pause standing tall between repetitions (sim/actions/strength.py
# draws the pauses; people pause so too). Under the edge bound alone a set's end kept only
# the recipe's hold (0.25-0.44 s) while a pause kept a second, and a model waited out the
# second at every end (experiments/set_switches.py: 10-11 frames at each of 9 squat and
# lunge set ends of a held-out lab session, 0-6 at most pauses).
PAUSING_ACTIONS: Final = ("squat", "lunge")
# Faster than a simulated quiet stand's sway (under 0.085 m/s, the same test).
STILL_SPEED_MPS: Final = 0.1
# Standing straight: a simulated quiet stand bends its knees 12 degrees, a
# squat's crouch 100 or more, a jump's 70-80 (tests/test_labelling_convention.py).
STANDING_KNEE_FLEXION_DEG: Final = 25.0


# --- ONNX graph I/O names --------------------------------------------------
# Streaming step: one new frame + cached embeddings of the previous T-1.
STEP_INPUT_FRAME: Final = "frame"  # float32 (B, H, 2W) raw counts, left|right
STEP_INPUT_PAST: Final = "past_embeddings"  # float32 (B, T-1, E), oldest first
# Window graph: B windows of T frames.
WINDOW_INPUT_FRAMES: Final = "frames"  # float32 (B, T, H, 2W) raw counts
OUTPUT_POSE: Final = "pose"  # float32 (B, 19, 3) metres, pose frame
OUTPUT_ACTION_LOGITS: Final = "action_logits"  # float32 (B, NUM_ACTIONS)
OUTPUT_PROGRESS: Final = "progress"  # float32 (B,) in [0, 1]; meaningless while standing
STEP_OUTPUT_EMBEDDING: Final = "embedding"  # float32 (B, E), the new frame's
# Both graphs, last output: the pooled representation the three heads read. The
# runtime scores it against the training data's statistics (``META_OOD``) for the
# ``unfamiliar`` flag (models/ood.py); a graph without it still runs, unscored.
OUTPUT_POOLED: Final = "pooled"  # float32 (B, E)

# Metadata keys (onnx metadata_props) every exported graph carries.
META_CONTRACT_VERSION: Final = "scotti.contract_version"
META_GRAPH: Final = "scotti.graph"  # "step" or "window"
META_WINDOW: Final = "scotti.window"  # T
META_EMBED_DIM: Final = "scotti.embed_dim"  # E
META_FRAME_ROWS: Final = "scotti.frame_rows"
META_FRAME_COLS: Final = "scotti.frame_cols"  # per foot (W)
META_KEYPOINTS: Final = "scotti.keypoints"  # JSON list
META_ACTIONS: Final = "scotti.actions"  # JSON list
META_CARD: Final = "scotti.card"  # JSON model card (training data, metrics, ...)
# Optional: statistics of the pooled vectors over training windows and the calibrated
# threshold of the unfamiliar score (JSON, models/ood.py ``OodStats``).
META_OOD: Final = "scotti.ood"
# Optional: a monotone map per action from the progress head's output to calibrated
# progress, fitted on held-out subjects (JSON, models/progress_calibration.py).
META_PROGRESS_CALIBRATION: Final = "scotti.progress_calibration"
