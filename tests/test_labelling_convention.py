"""One labelling convention for every source of labels (models/contract.py, "The labelling
convention"): the same squats with pauses, asked by a script, by a lab session and brought
in by ``scotti import``, get the same labels frame for frame; the edges of a set and its
pauses keep at most SET_EDGE_REST_S of still standing, wherever the labels come from."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.session import read_session
from scotti.models.contract import (
    ACTIONS,
    FRAME_RATE_HZ,
    KEYPOINTS,
    KP,
    NO_ACTION,
    SET_EDGE_REST_S,
    STANDING,
    STANDING_KNEE_FLEXION_DEG,
    STILL_SPEED_MPS,
)
from scotti.models.set_edges import frame_speeds, knee_flexion_deg, set_edges
from scotti.sim.actions import Context, Segment
from scotti.sim.motion import Labels, Motion, labels
from scotti.sim.scene import (
    LEAD_IN_S,
    Scene,
    ScriptEntry,
    SubjectModel,
    build_motion,
    motion_from_segments,
    script_segments,
    with_set_edges,
)
from scotti.sim.session import Item, SessionModel, build_session, session_segments

SQUAT = ACTIONS.index("squat")
REPS = 4
STAND_S = 1.5
# Pauses of about a second between repetitions (the trait's top is 1.5 s).
SUBJECT = SubjectModel(height_m=1.75, mass_kg=72.0, style_seed=11, rep_pause_s=1.2)
EDGE = round(SET_EDGE_REST_S * FRAME_RATE_HZ)


def _context(seed: int) -> Context:
    subject = SUBJECT.subject()
    return Context(subject.body(), subject, FRAME_RATE_HZ, np.random.default_rng(seed))


def _labelled(ctx: Context, segments: list[Segment]) -> tuple[Motion, Labels]:
    motion = with_set_edges(motion_from_segments(ctx.body, ctx.subject, ctx.rate_hz, segments))
    return motion, labels(motion)


def scripted(seed: int) -> tuple[Motion, Labels]:
    """A script's set: lead-in stand, REPS squats, a stand of STAND_S."""
    ctx = _context(seed)
    entry = ScriptEntry(action="squat", reps=REPS, stand_s=STAND_S)
    return _labelled(ctx, script_segments(ctx, [entry]))


def in_the_lab(seed: int) -> tuple[Motion, Labels]:
    """The same set as a lab session asks it: a set of so many seconds (which makes REPS
    repetitions), with the stands of the same lengths around it."""
    ctx = _context(seed)
    traits = ctx.subject.traits
    seconds = (REPS - 0.5) * (traits.squat_rep_s + traits.rep_pause_s)
    items = [Item("stand", LEAD_IN_S), Item("set", seconds, "squat"), Item("stand", STAND_S)]
    # Minutes far below the set: no set is topped up.
    segments, _ = build_session(ctx, items, {"squat": 0.01}, (5.0, 20.0), np.random.default_rng(0))
    return _labelled(ctx, segments)


def _runs(values: np.ndarray) -> list[tuple[int, int]]:
    starts = np.flatnonzero(np.r_[True, values[1:] != values[:-1]])
    return list(zip(starts.tolist(), np.r_[starts[1:], values.size].tolist(), strict=True))


def test_a_script_and_a_lab_session_label_the_same_set_the_same() -> None:
    script_motion, script = scripted(seed=4)
    lab_motion, lab = in_the_lab(seed=4)
    # The same request makes the same motion (the precondition), and the same labels.
    np.testing.assert_array_equal(script_motion.world, lab_motion.world)
    np.testing.assert_array_equal(script.action, lab.action)
    np.testing.assert_array_equal(script.progress, lab.progress)
    np.testing.assert_array_equal(script.repetition, lab.repetition)


def test_a_pause_is_the_set_for_a_second_then_standing_as_are_the_stands_around_it() -> None:
    _, lab = scripted(seed=4)
    runs = _runs(lab.action)
    assert int(lab.action[runs[0][0]]) == STANDING
    assert int(lab.action[runs[-1][0]]) == STANDING
    assert runs[0][1] == round(LEAD_IN_S * FRAME_RATE_HZ)
    assert set(lab.action.tolist()) == {STANDING, SQUAT}
    assert np.isnan(lab.progress[lab.action == STANDING]).all()
    assert (lab.repetition[lab.action == STANDING] == -1).all()

    start, end = runs[1][0], runs[-1][0]  # the set, from its first squat to the last
    moving = frame_speeds(lab.keypoints[start:end], FRAME_RATE_HZ) >= STILL_SPEED_MPS
    first, last = np.flatnonzero(moving)[[0, -1]]
    # The set's still lead is the recipe's own, shorter than the convention's bound; after
    # its last movement a squat set keeps exactly the bound, as a pause does.
    assert 0 < first <= EDGE
    assert end - start - 1 - last == EDGE
    # Pauses between repetitions: stretches still at the top between the first and the
    # last movement (the bottom of a squat is held a moment too: no pause).
    hips = lab.keypoints[start:end, 7:9, 2].mean(axis=1)
    at_top = ~moving & (hips > hips.max() - 0.01)
    pauses = [(a, b) for a, b in _runs(at_top.astype(int)) if at_top[a] and first < a < last]
    assert len(pauses) == REPS - 1
    long = [(a, b) for a, b in pauses if b - a > EDGE]
    assert long  # this person pauses both ways
    assert len(long) < len(pauses)
    for a, b in pauses:
        held = lab.action[start + a : start + min(b, a + EDGE)]
        assert (held == SQUAT).all()  # the first second is the set's ...
        assert lab.progress[start + a : start + a + held.size].max() < 0.05  # ... at ~0
        assert (lab.action[start + a + EDGE : start + b] == STANDING).all()  # then standing
    # A repetition ends on arrival at the top: the count steps up as the hips get there,
    # and a run that a pause ends holds the repetitions completed in it.
    squats = lab.action[start:end] == SQUAT
    completed = 0
    for a, b in _runs(squats.astype(int)):
        if not squats[a]:
            continue
        steps = np.flatnonzero(np.diff(lab.repetition[start + a : start + b])) + 1
        for step in steps:
            assert hips[a + step] > hips.max() - 0.04 > hips[a + step - 2]  # just risen
        completed += int(lab.repetition[start + b - 1])
    assert completed == REPS


def test_lab_sessions_change_only_pauses_and_the_ends_of_pausing_sets() -> None:
    """The figures in contract.py: at tempo 1 the sets' still edges stay within 0.6 s and a
    quiet stand's sway under 0.085 m/s (< STILL_SPEED_MPS), so the edge bound trims
    nothing: what set_edges changes is pauses inside sets, standing straight-legged, and
    the standing right after a squat or lunge set, which becomes the set's up to a second
    after its last movement."""
    scene = Scene(
        seed=5,
        subject=SubjectModel(height_m=1.68, mass_kg=63.0, style_seed=8),
        session=SessionModel(minutes_per_action=0.5, set_s=(15.0, 25.0), rest_s=(5.0, 10.0)),
    )
    subject = scene.subject_model()
    seeds = np.random.SeedSequence([scene.seed, subject.style_seed])
    ctx = Context(subject.body(), subject, FRAME_RATE_HZ, np.random.default_rng(seeds))
    assert scene.session is not None
    segments = session_segments(scene.session, ctx, scene.seed)
    motion = motion_from_segments(ctx.body, subject, FRAME_RATE_HZ, segments)  # the recipes' labels
    np.testing.assert_array_equal(motion.world, build_motion(scene).world)  # the scene's motion
    keypoints = motion.pose_frame()
    held = set_edges(keypoints, motion.action, FRAME_RATE_HZ)
    changed = np.flatnonzero(held != motion.action)
    to_standing = changed[held[changed] == STANDING]
    taken = changed[held[changed] != STANDING]
    assert to_standing.size  # this session's sets pause longer than the bound
    assert taken.size  # and its squat and lunge sets end standing
    assert (knee_flexion_deg(keypoints[changed]) < STANDING_KNEE_FLEXION_DEG).all()
    assert (motion.action[taken] == STANDING).all()
    assert {ACTIONS[a] for a in held[taken]} == {"squat", "lunge"}
    for start, end in _runs(motion.action):
        action = int(motion.action[start])
        speed = frame_speeds(keypoints[start:end], FRAME_RATE_HZ)
        moving = np.flatnonzero(speed >= STILL_SPEED_MPS)
        inside = to_standing[(to_standing >= start) & (to_standing < end)]
        if inside.size:  # every pause relabelled lies between a set's movements
            assert moving[0] < inside.min() - start
            assert inside.max() - start < moving[-1]
        if action in (ACTIONS.index("squat"), ACTIONS.index("lunge")):
            # The set's label now runs to a second after its last movement.
            run_end = end + int(np.sum(np.isin(taken, np.arange(end, end + EDGE))))
            assert (held[start + moving[-1] + 1 : run_end] == action).all()
            assert run_end - (start + moving[-1] + 1) == EDGE
    speed = frame_speeds(keypoints, FRAME_RATE_HZ)
    assert speed[motion.action == STANDING].max() < 0.085
    edges = []
    for start, end in _runs(motion.action):
        if int(motion.action[start]) in (STANDING, NO_ACTION):
            continue
        moving = np.flatnonzero(
            frame_speeds(keypoints[start:end], FRAME_RATE_HZ) >= STILL_SPEED_MPS
        )
        assert moving.size, ACTIONS[motion.action[start]]
        edges += [moving[0], end - start - 1 - moving[-1]]
    assert max(edges) / FRAME_RATE_HZ <= 0.6


def _import(session: Labels, d: Path, segments: str) -> Labels:
    """``scotti import`` of the session's keypoints (world frame, metres, z up) with a
    segment file; pressure is a flat 50 kPa (labels do not read it)."""
    n = len(session.action)
    t = np.arange(n) / FRAME_RATE_HZ
    np.savez(d / "p.npz", time=t, left=np.full((n, 4, 4), 50.0), right=np.full((n, 4, 4), 50.0))
    (d / "segments.csv").write_text(segments)
    mapping = ", ".join(f'{name} = "{name}"' for name in KEYPOINTS)
    names = np.array(KEYPOINTS)
    np.savez(d / "pose.npz", time=t, keypoints=session.keypoints.astype(np.float64), names=names)
    (d / "import.toml").write_text(
        'subject = "p01"\n[pressure]\nfile = "p.npz"\nrows = 4\ncols = 4\n'
        '[counts]\nmethod = "per_kpa"\nunits_per_kpa = 1.0\n'
        '[keypoints]\nfile = "pose.npz"\nset = "custom"\nfloor_z = 0.0\n'
        f"mapping = {{ {mapping} }}\n"
        '[labels]\nsegments = "segments.csv"\n'
    )
    out = d / "p01.scotti"
    assert main(["import", str(d / "import.toml"), "-o", str(out), "--force"]) == 0
    records = read_session(out).labels
    assert len(records) == n
    return Labels(
        np.stack([r.keypoints for r in records]),
        np.array([r.action for r in records]),
        np.array([r.progress for r in records], dtype=np.float32),
        np.array([r.rep for r in records]),
    )


def _segment_file(rows: list[tuple[int, int, int]]) -> str:
    """Frames [s, e) as segments; each ends half a frame after its last frame (the
    recording's last frame has nothing after it)."""
    lines = ["start,end,action"]
    rate = FRAME_RATE_HZ
    lines += [f"{s / rate:g},{(e - 0.5) / rate:g},{ACTIONS[a]}" for s, e, a in rows]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def lab_set() -> Labels:
    """The lab's set in the session's pose frame, as the session file holds it; standing
    for 3 s before and after, longer than the convention keeps with a set."""
    ctx = _context(seed=4)
    traits = ctx.subject.traits
    seconds = (REPS - 0.5) * (traits.squat_rep_s + traits.rep_pause_s)
    items = [Item("stand", 3.0), Item("set", seconds, "squat"), Item("stand", 3.0)]
    segments, _ = build_session(ctx, items, {"squat": 0.01}, (5.0, 20.0), np.random.default_rng(0))
    return _labelled(ctx, segments)[1]


def test_an_import_of_the_same_motion_gets_the_same_labels(lab_set: Labels, tmp_path: Path) -> None:
    rows = [(s, e, int(lab_set.action[s])) for s, e in _runs(lab_set.action)]
    imported = _import(lab_set, tmp_path, _segment_file(rows))
    np.testing.assert_array_equal(imported.action, lab_set.action)
    np.testing.assert_array_equal(np.isnan(imported.progress), np.isnan(lab_set.progress))
    np.testing.assert_allclose(imported.progress, lab_set.progress, atol=1e-5)
    np.testing.assert_array_equal(imported.repetition, lab_set.repetition)


def test_an_import_that_calls_the_stands_squat_keeps_a_second_of_them(
    lab_set: Labels, tmp_path: Path
) -> None:
    """A loose segment file (squat from the first frame to the last): the pauses stay squat
    as in the lab; the stands beyond SET_EDGE_REST_S of the first and last movement become
    standing. After the last movement both keep exactly the second; before the first the
    importer cannot know where the set began, and keeps squat where the lab's lead-in is
    shorter."""
    n = len(lab_set.action)
    imported = _import(lab_set, tmp_path, _segment_file([(0, n, SQUAT)]))
    moving = frame_speeds(imported.keypoints, FRAME_RATE_HZ) >= STILL_SPEED_MPS
    first, last = np.flatnonzero(moving)[[0, -1]]
    assert (lab_set.action[last + 1 : last + 1 + EDGE] == SQUAT).all()  # the end: the same
    assert lab_set.action[last + 1 + EDGE] == STANDING
    margin = np.zeros(n, dtype=bool)
    margin[first - EDGE : first] = True
    margin &= lab_set.action == STANDING  # where the lab's own lead-in ends sooner
    assert margin.any()  # the two sources do differ there ...
    assert (imported.action[margin] == SQUAT).all()  # ... the import keeps squat, ~0
    assert np.nanmax(imported.progress[margin]) < 0.05
    same = ~margin
    np.testing.assert_array_equal(imported.action[same], lab_set.action[same])
    assert (imported.action[: first - EDGE] == STANDING).all()
    assert (imported.action[last + 1 + EDGE :] == STANDING).all()
    # Progress and repetitions inside the set hardly depend on where the file put its edges
    # (the longer lead's hip sway, under a millimetre, enters the first repetition's extremes).
    inside = same & (lab_set.action == SQUAT)
    np.testing.assert_allclose(imported.progress[inside], lab_set.progress[inside], atol=1e-3)
    steps = np.flatnonzero(np.diff(imported.repetition[inside]))
    np.testing.assert_array_equal(steps, np.flatnonzero(np.diff(lab_set.repetition[inside])))


# --- the edge rule itself, on hand-made keypoints -------------------------------------


def _bobbing(
    still_before: float, still_after: float, pause: float = 0.0, *, pause_low: bool = False
) -> np.ndarray:
    """(N, 19, 3): standing still, then two 2 s dips of the hips by 0.3 m (a pause between
    them, standing tall or, ``pause_low``, held at the bottom), then still again. The knees
    go forward as the hips drop: about 5 degrees of flexion standing, 70 at the bottom."""
    rate = FRAME_RATE_HZ
    pieces = [np.zeros(round(still_before * rate))]
    dip = 0.15 * (1.0 - np.cos(2.0 * math.pi * np.arange(round(2.0 * rate)) / (2.0 * rate)))
    half = dip.size // 2
    if pause_low:
        pieces += [dip[:half], np.full(round(pause * rate), 0.3), dip[half:]]
    else:
        pieces += [dip, np.zeros(round(pause * rate))]
    pieces += [dip, np.zeros(round(still_after * rate))]
    drop = np.concatenate(pieces)
    k = np.zeros((drop.size, len(KEYPOINTS), 3))
    k[:, :, 2] = 1.4 - drop[:, None]  # the upper body rides on the hips
    for side, y in (("left", 0.1), ("right", -0.1)):
        k[:, KP[f"{side}_hip"]] = np.stack(
            [np.zeros_like(drop), np.full_like(drop, y), 0.95 - drop], 1
        )
        k[:, KP[f"{side}_knee"]] = np.stack(
            [0.02 + 0.5 * drop, np.full_like(drop, y), np.full_like(drop, 0.5)], 1
        )
        for foot in ("ankle", "heel", "big_toe", "small_toe"):
            k[:, KP[f"{side}_{foot}"]] = [0.0, y, 0.08]
    return k


def _longest_still(moving: np.ndarray) -> tuple[int, int]:
    """[from, to) of the longest still stretch between two moving frames."""
    gaps = [(int(a) + 1, int(b)) for a, b in itertools.pairwise(moving)]
    return max(gaps, key=lambda g: g[1] - g[0])


def test_still_edges_and_pauses_beyond_the_bound_become_standing() -> None:
    k = _bobbing(3.0, 2.5, pause=4.0)
    action = np.full(len(k), SQUAT)
    out = set_edges(k, action, FRAME_RATE_HZ)
    moving = np.flatnonzero(frame_speeds(k, FRAME_RATE_HZ) >= STILL_SPEED_MPS)
    first, last = moving[0], moving[-1]
    pause_from, pause_to = _longest_still(moving)
    assert pause_to - pause_from >= round(4.0 * FRAME_RATE_HZ)  # the 4 s stand, seen
    assert (out[: first - EDGE] == STANDING).all()
    assert (out[first - EDGE : pause_from + EDGE] == SQUAT).all()  # the pause's first second
    assert (out[pause_from + EDGE : pause_to] == STANDING).all()  # the rest of it
    assert (out[pause_to : last + 1 + EDGE] == SQUAT).all()  # the next movement on
    assert (out[last + 1 + EDGE :] == STANDING).all()
    np.testing.assert_array_equal(action, SQUAT)  # the input is left as it was
    # A pause of at most the bound is the set's, whole.
    short = _bobbing(3.0, 2.5, pause=SET_EDGE_REST_S - 0.1)
    held = set_edges(short, np.full(len(short), SQUAT), FRAME_RATE_HZ)
    assert [int(held[a]) for a, _ in _runs(held)] == [STANDING, SQUAT, STANDING]


def test_a_pause_held_low_is_no_standing() -> None:
    """4 s held at the bottom of the dip: still, but the knees bent 70 degrees."""
    k = _bobbing(3.0, 2.5, pause=4.0, pause_low=True)
    assert knee_flexion_deg(k).max() > 60.0 > 10.0 > knee_flexion_deg(k[:10]).max()
    out = set_edges(k, np.full(len(k), SQUAT), FRAME_RATE_HZ)
    assert [int(out[a]) for a, _ in _runs(out)] == [STANDING, SQUAT, STANDING]


def test_a_pause_the_keypoints_do_not_show_keeps_its_label() -> None:
    k = _bobbing(3.0, 2.5, pause=4.0)
    moving = np.flatnonzero(frame_speeds(k, FRAME_RATE_HZ) >= STILL_SPEED_MPS)
    pause_from, _ = _longest_still(moving)
    masked = k.copy()
    masked[pause_from + 30] = np.nan  # one unseen frame in the pause
    out = set_edges(masked, np.full(len(k), SQUAT), FRAME_RATE_HZ)
    assert [int(out[a]) for a, _ in _runs(out)] == [STANDING, SQUAT, STANDING]


def test_what_the_keypoints_do_not_show_keeps_its_label() -> None:
    k = _bobbing(3.0, 3.0)
    action = np.full(len(k), SQUAT)
    masked = k.copy()
    masked[5] = np.nan  # an unseen frame in the leading stand
    out = set_edges(masked, action, FRAME_RATE_HZ)
    assert (out[:10] == SQUAT).all()
    assert out[-1] == STANDING  # the trailing stand is seen: held to the bound
    # Standing, transitions and actions without repetitions are never relabelled.
    for other in (STANDING, NO_ACTION):
        np.testing.assert_array_equal(set_edges(k, np.full(len(k), other), FRAME_RATE_HZ), other)


def test_a_set_in_which_nothing_moves_is_the_standing_it_shows() -> None:
    """A "squat set" standing straight and still throughout is standing, as the same
    frames labelled standing are; held in a crouch or partly unseen, it keeps its label."""
    standing = _bobbing(5.0, 0.0)[:80]  # the first 5 s: tall and still
    assert frame_speeds(standing, FRAME_RATE_HZ).max() < STILL_SPEED_MPS
    for action in (SQUAT, ACTIONS.index("lunge")):
        out = set_edges(standing, np.full(len(standing), action), FRAME_RATE_HZ)
        np.testing.assert_array_equal(out, STANDING)
    # Inside a longer recording: the still run alone turns, its neighbours stay.
    k = np.concatenate([_bobbing(0.0, 0.0), standing])
    given = np.r_[np.full(len(k) - 80, ACTIONS.index("walking")), np.full(80, SQUAT)]
    out = set_edges(k, given, FRAME_RATE_HZ)
    np.testing.assert_array_equal(out[:-80], given[:-80])
    np.testing.assert_array_equal(out[-80:], STANDING)
    crouched = _bobbing(0.0, 0.0, pause=5.0, pause_low=True)
    bent = knee_flexion_deg(crouched).min(axis=1) > 60.0
    low = np.flatnonzero(bent & (frame_speeds(crouched, FRAME_RATE_HZ) == 0.0))
    held_low = crouched[low[0] : low[0] + 60]  # still, knees bent 70 degrees
    assert frame_speeds(held_low, FRAME_RATE_HZ).max() < STILL_SPEED_MPS
    np.testing.assert_array_equal(set_edges(held_low, np.full(60, SQUAT), FRAME_RATE_HZ), SQUAT)
    unseen = standing.copy()
    unseen[40] = np.nan
    np.testing.assert_array_equal(set_edges(unseen, np.full(80, SQUAT), FRAME_RATE_HZ), SQUAT)


def test_a_scripted_squat_of_depth_0_is_labelled_standing(tmp_path: Path) -> None:
    """The coverage grid's squat at the schema's smallest depth: the person never bends,
    so every frame of the session says standing, as a scene of standing would."""
    scene = tmp_path / "squat0.toml"
    scene.write_text(
        "seed = 1\nrate = 16.0\n[subject]\nheight_m = 1.75\nmass_kg = 72.0\n"
        'style_seed = 11\n[[script]]\naction = "squat"\nreps = 4\ndepth = 0.0\n'
    )
    out = tmp_path / "squat0.ses"
    assert main(["sim", str(scene), "-o", str(out)]) == 0
    actions = np.array([label.action for label in read_session(out).labels])
    assert actions.size > 100
    np.testing.assert_array_equal(actions, STANDING)


def test_a_gap_ends_a_run() -> None:
    k = np.concatenate([_bobbing(0.0, 3.0), _bobbing(3.0, 0.0)])
    action = np.full(len(k), SQUAT)
    half = len(k) // 2
    moving = np.flatnonzero(frame_speeds(k, FRAME_RATE_HZ) >= STILL_SPEED_MPS)
    pause_from, pause_to = _longest_still(moving)
    # One run: the 6 s still in the middle is a pause: the set's for a second, then
    # standing up to the next movement (a run's lead is no pause's).
    one = set_edges(k, action, FRAME_RATE_HZ)
    assert (one[: pause_from + EDGE] == SQUAT).all()
    assert (one[pause_from + EDGE : pause_to] == STANDING).all()
    assert (one[pause_to:] == SQUAT).all()
    # Two runs: each edge is held, the second run's lead keeps its second before moving.
    split = set_edges(k, action, FRAME_RATE_HZ, segment=np.repeat([0, 1], half))
    assert (split[half - 10 : half + 10] == STANDING).all()
    assert (split[pause_to - EDGE : pause_to] == SQUAT).all()
    assert (one[pause_to - EDGE : pause_to] == STANDING).all()


def test_a_pausing_set_takes_the_standing_after_its_last_movement_up_to_the_bound() -> None:
    """The source ends the squat set 3 frames after its last movement and calls the rest
    standing: the set takes the standing up to SET_EDGE_REST_S after that movement, as a
    pause's first second; a walking set (its sets do not pause) keeps its own end."""
    k = _bobbing(3.0, 3.0)
    moving = np.flatnonzero(frame_speeds(k, FRAME_RATE_HZ) >= STILL_SPEED_MPS)
    first, last = moving[0], moving[-1]
    given = np.full(len(k), STANDING)
    given[first : last + 4] = SQUAT
    out = set_edges(k, given, FRAME_RATE_HZ)
    assert (out[first : last + 1 + EDGE] == SQUAT).all()
    assert (out[last + 1 + EDGE :] == STANDING).all()
    assert (out[:first] == STANDING).all()  # the lead is not taken: no set starts unseen
    np.testing.assert_array_equal(given[last + 4 :], STANDING)  # the input is left as it was
    walking = ACTIONS.index("walking")
    given_walking = np.where(given == SQUAT, walking, STANDING)
    np.testing.assert_array_equal(set_edges(k, given_walking, FRAME_RATE_HZ), given_walking)


def test_the_standing_a_set_takes_stops_at_movement_bent_knees_or_a_gap() -> None:
    k = _bobbing(3.0, 3.0)
    moving = np.flatnonzero(frame_speeds(k, FRAME_RATE_HZ) >= STILL_SPEED_MPS)
    last = moving[-1]
    given = np.full(len(k), STANDING)
    given[: last + 1] = SQUAT
    # A step 5 frames after the last movement: the set takes the 4 still frames before it.
    stepped = k.copy()
    stepped[last + 5 :, :, 0] += 0.05
    out = set_edges(stepped, given, FRAME_RATE_HZ)
    assert (out[last + 1 : last + 5] == SQUAT).all()
    assert (out[last + 5 :] == STANDING).all()
    # Knees bent past STANDING_KNEE_FLEXION_DEG from 6 frames on: 5 taken.
    crouched = k.copy()
    for side in ("left", "right"):
        crouched[last + 6 :, KP[f"{side}_knee"], 0] += 0.4
    assert knee_flexion_deg(crouched[last + 6 : last + 7]).min() > STANDING_KNEE_FLEXION_DEG
    out = set_edges(crouched, given, FRAME_RATE_HZ)
    assert (out[last + 1 : last + 6] == SQUAT).all()
    assert (out[last + 6 :] == STANDING).all()
    # A gap (another segment) 3 frames after: 2 taken.
    segment = np.zeros(len(k), np.int64)
    segment[last + 3 :] = 1
    out = set_edges(k, given, FRAME_RATE_HZ, segment=segment)
    assert (out[last + 1 : last + 3] == SQUAT).all()
    assert (out[last + 3 :] == STANDING).all()
