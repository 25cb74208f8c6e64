"""Labels and calibration: segments per frame, progress only where it can be computed,
counts by body mass, config mistakes located."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.importers.config import LabelsConfig, config_from_dict, load_config
from scotti.importers.errors import InputError
from scotti.importers.labels import frame_actions, frame_progress, read_segments
from scotti.importers.pressure import CountMapper, read_pressure
from scotti.models.contract import ACTIONS, KP, NO_ACTION
from scotti.models.insole import insole_mask

from tests.support.foreign import squat_pose


def test_segments_give_each_frame_its_action(tmp_path: Path) -> None:
    path = tmp_path / "seg.csv"
    path.write_text("start,end,action\n0.5,1.0,squat\n\n1.0,1.5,lunge\n")
    segments = read_segments(path, LabelsConfig(segments="seg.csv"), 100.0, 102.0)
    t = 100.0 + np.arange(0, 2.0, 0.25)
    got = frame_actions(t, segments)
    squat, lunge = ACTIONS.index("squat"), ACTIONS.index("lunge")
    assert got.tolist() == [NO_ACTION, NO_ACTION, squat, squat, lunge, lunge, NO_ACTION, NO_ACTION]
    path.write_text("0.5,1.0,squat\n0.8,1.2,lunge\n")
    with pytest.raises(InputError, match=r"seg\.csv line 2, column 1: overlaps"):
        read_segments(path, LabelsConfig(segments="seg.csv"), 100.0, 102.0)


def test_progress_is_missing_where_its_keypoints_are() -> None:
    t = np.arange(0, 6, 1 / 16)
    keypoints = squat_pose(t)
    keypoints[40:50, KP["left_hip"]] = np.nan  # the mid-hip indicator is unknown here
    action = np.full(t.size, ACTIONS.index("squat"))
    action[:8] = NO_ACTION
    segment = np.zeros(t.size, dtype=np.int32)
    progress, repetition = frame_progress(keypoints, action, segment)
    assert np.isnan(progress[:8]).all()
    assert np.isnan(progress[40:50]).all()
    known = np.r_[8:40, 50 : t.size]
    assert np.isfinite(progress[known]).all()
    assert ((progress[known] >= 0) & (progress[known] <= 1)).all()
    # 2 s squats, bottoms at 1 s, 3 s (masked) and 5 s: progress 0.5 there.
    assert progress[[16, 80]] == pytest.approx([0.5, 0.5], abs=0.05)
    assert repetition[8] >= 0


def test_body_mass_calibration_by_hand(tmp_path: Path) -> None:
    # Both feet 8 x 11 taxels of 40 mm^2, every taxel reads 7 units while standing.
    # Carrying m g = 128 kPa x 176 x 40 mm^2 = 901.12 N makes 7 units 128 kPa,
    # and 128 kPa is 4095 * 108^0.8 / (108^0.8 + 180^0.8) = 1634.9 -> 1635 counts on our
    # scale (models/insole.py: threshold 20 kPa, half scale 180 kPa above it, power 0.8).
    n = 20
    np.savez(
        tmp_path / "p.npz",
        time=np.arange(n) / 10,
        left=np.full((n, 8, 11), 7.0),
        right=np.full((n, 8, 11), 7.0),
    )
    cfg = config_from_dict(
        {
            "pressure": {"file": "p.npz", "rows": 8, "cols": 11},
            "counts": {
                "method": "body_mass",
                "mass_kg": 901.12 / 9.81,
                "stand_s": [0.0, 1.0],
                "taxel_area_mm2": 40.0,
            },
            "base_dir": str(tmp_path),
        }
    )
    source = read_pressure(cfg)
    mapper = CountMapper(cfg, source)
    assert mapper.kpa_per_unit == pytest.approx(128.0 / 7.0)
    counts = mapper(source.frames[:1])[0]
    mask = insole_mask()
    assert (counts[:, mask] == 1635).all()
    assert (counts[:, ~mask] == 0).all()


def test_config_mistakes_name_the_line_and_field(tmp_path: Path) -> None:
    path = tmp_path / "import.toml"
    path.write_text('[pressure]\nfile = "p.csv"\nrows = 0\ncols = 3\n')
    with pytest.raises(InputError, match=r"import\.toml line 3: pressure\.rows: Input should be"):
        load_config(path)
    path.write_text(
        '[pressure]\nfile = "p.csv"\nrows = 2\ncols = 3\n[counts]\nmethod = "per_kpa"\n'
    )
    with pytest.raises(InputError, match="needs units_per_kpa"):
        load_config(path)
    path.write_text('[pressure]\nfile = "p.csv"\nrows = 2\ncols = 3\n[labels]\naction = "dance"\n')
    with pytest.raises(InputError, match=r"line 6: labels\.action: Value error, 'dance' is not"):
        load_config(path)
    path.write_text('[pressure\nfile = "p.csv"\n')
    with pytest.raises(InputError, match=r"import\.toml line 1: "):
        load_config(path)


def test_mapping_file_and_absolute_segment_times(tmp_path: Path) -> None:
    from scotti.importers.config import load_mapping

    path = tmp_path / "mapping.toml"
    path.write_text('[mapping]\nleft_hip = "LH"\nright_hip = 3\n')
    assert load_mapping(path) == {"left_hip": "LH", "right_hip": 3}
    path.write_text('[mapping]\nleft_hip = "LH"\npelvis = "P"\n')
    with pytest.raises(InputError, match=r"mapping\.toml line 3: 'pelvis' is not one of our"):
        load_mapping(path)
    seg = tmp_path / "seg.csv"
    seg.write_text("1700000001000,1700000002000,walking\n")
    labels = LabelsConfig(segments="seg.csv", time="absolute", time_unit="ms")
    segments = read_segments(seg, labels, 1_700_000_000.0, 1_700_000_003.0)
    assert (segments[0].start_s, segments[0].end_s) == (1_700_000_001.0, 1_700_000_002.0)


def test_an_outline_file_zeroes_taxels_the_source_lacks(tmp_path: Path) -> None:
    # 4 x 11 source; the outline (as stored) lacks the last column, which is medial
    # (medial = "last_col"): after turning, our columns 0 and 1 get nothing.
    n = 4
    np.savez(tmp_path / "p.npz", time=np.arange(n) / 10,
             left=np.full((n, 4, 11), 128.0), right=np.full((n, 4, 11), 128.0))  # fmt: skip
    outline = np.ones((4, 11), dtype=int)
    outline[:, -1] = 0
    np.savetxt(tmp_path / "outline.csv", outline, fmt="%d", delimiter=",")
    cfg = config_from_dict(
        {
            "pressure": {
                "file": "p.npz",
                "rows": 4,
                "cols": 11,
                "left": {"medial": "last_col", "outline": "outline.csv"},
            },
            "counts": {"method": "per_kpa", "units_per_kpa": 1.0},
            "base_dir": str(tmp_path),
        }
    )
    source = read_pressure(cfg)
    counts = CountMapper(cfg, source)(source.frames[:1])[0]
    mask = insole_mask()
    assert (counts[0][:, :2] == 0).all()
    assert (counts[0][:, 2:][mask[:, 2:]] == 1635).all()  # 128 kPa, as above
    assert (counts[1][mask] == 1635).all()  # the right foot has no outline file
    np.savetxt(tmp_path / "outline.csv", outline[:, :5], fmt="%d", delimiter=",")
    with pytest.raises(InputError, match=r"outline is 4 x 5, the grid 4 x 11"):
        CountMapper(cfg, source)
