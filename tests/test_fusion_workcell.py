"""Issue 4's workcell experiment (depthguard_lab.experiments.fusion_workcell): one depth camera against two fused through
the depth grid, in reference scenario B's shadow and hidden-hand cases, with the second camera across the robot
(scenario_b_across.yaml). The fused result never misses and never reports less than the principal camera alone; in
the hidden-hand case it finds the hand the principal camera cannot see. In the shadow case it cannot remove the
principal camera's false alarms: what the shadow hides next to the robot, the links hide from the second camera.
Plus the summary and plots on a small hand-made episode, and the command line."""

import json

import numpy as np
import pytest

import depthguard as dg
from depthguard_lab.experiments import fusion_workcell as fw
from depthguard_lab.simulation import load_workcell, simulate

RHO = fw.RHO
FRAMES_PER_CASE = 4
#: Footprints of discretisation a distance may exceed the truth by, and metres of depth quantisation on top: the
#: single-camera bound of tests/test_workcell_episode.py (``allowed_excess``, derived there): sqrt(2) footprints at
#: a silhouette plus one for a dropout filled by invalid="neighbors", rounded up; 1 mm for the millimetre images.
FOOTPRINTS = 2.5
QUANTISATION = 1e-3


@pytest.fixture(scope="module")
def across():
    (path,) = [p for p in fw.scene_paths() if p.name == "scenario_b_across.yaml"]
    return load_workcell(path)


def _hold_times(workcell, kind):
    """(start, end) seconds of the part of action ``kind`` where the person is in place (after walking there)."""
    (span,) = [s for s in workcell.timeline() if s.kind == kind]
    return span.hold_start, span.end


@pytest.fixture(scope="module")
def episode(across):
    # The scene's own 640x480 cameras (the sensor's dropouts depend on the resolution). A few frames spread over each
    # case while the person is in place: the shadow case, and the hidden hand fully held out (after its 0.25 s ramp).
    frames = []
    for kind in fw.CASES:
        start, end = _hold_times(across, kind)
        times = np.linspace(start + 0.3, end - 0.3, FRAMES_PER_CASE)
        frames += [int(round(t * across.rate)) for t in times]
    return fw.run(across, layout="scenario_b_across", frames=frames, progress=False)


@pytest.fixture(scope="module")
def allowed(across, episode):
    """(k, t, m) metres each method's distance may exceed the truth by, stated here (not the episode's record).

    Each camera alone: FOOTPRINTS footprints at the deepest a nearest obstacle point within rho can lie,
    (max(z, 0.1 m) + rho) / f for a control point at optical depth z, plus QUANTISATION. Fused: the principal
    camera's (tests/fusion_scenes.py: the principal's pixels make the grid's cells, so a fused distance's
    discretisation is the principal's at Q; a secondary camera only clears cells, and a wrongly cleared cell is an
    error, not a tolerance)."""
    points = [across.control_points_at(t) for t in episode.times]
    singles = []
    cameras = [m for m in episode.methods if m not in fw.FUSED_METHODS]
    for name in cameras:
        camera = across.rig.cameras[name]
        depth = np.array([camera.world_to_camera(p)[:, 2] for p in points])
        singles.append(FOOTPRINTS * (np.maximum(depth, 0.1) + RHO) / camera.fx + QUANTISATION)
    assert episode.methods[0] == across.rig.principal
    return np.stack(singles + [singles[0]] * len(fw.FUSED_METHODS))


def test_the_experiment_judges_no_more_loosely_than_these_tests(episode, allowed):
    """The experiment's summary counts misses with its own tolerance (the fused one: the larger of the cameras'):
    loosening it must fail here."""
    n = len(fw.FUSED_METHODS)
    assert episode.methods[-n:] == fw.FUSED_METHODS
    assert np.all(episode.tolerance[:-n] <= allowed[:-n] + 1e-12)
    assert np.all(episode.tolerance[-n:] <= allowed[:-n].max(axis=0) + 1e-12)


def _case(episode, kind):
    rows = fw.case_rows(episode, kind)
    assert rows.sum() == FRAMES_PER_CASE
    return rows


def _method(episode, allowed, name, rows):
    """(reported, tolerance, flags) of one method over the frames ``rows``: (t, m) each; the tolerance is
    ``allowed``'s (the fixture's)."""
    k = episode.methods.index(name)
    return episode.reported[k][rows], allowed[k][rows], episode.flags[k][rows]


def test_the_across_layout_moves_only_the_second_camera(across):
    from depthguard_lab.simulation import default_workcell

    reference = default_workcell()
    a, b = dict(reference.scene), dict(across.scene)
    (a_principal, a_second), (b_principal, b_second) = a.pop("cameras"), b.pop("cameras")
    assert a == b and a_principal == b_principal
    a_second, b_second = dict(a_second), dict(b_second)
    assert a_second.pop("look_at")["target"] == b_second.pop("look_at")["target"] and a_second == b_second
    eyes = {name: cam.T_world_camera[:3, 3] for name, cam in across.rig.cameras.items()}
    assert 3.5 < np.linalg.norm(eyes["second"] - eyes["principal"]) < 4.5  # design: about 4 m apart
    # Inside the room (walls at x = -2.2, y = +-3.0, up to z = 2.0), and across the robot: seen from the point both
    # cameras look at, more than 150 degrees apart (the reference layout: 114).
    assert -2.2 < eyes["second"][0] and abs(eyes["second"][1]) < 3.0 and eyes["second"][2] < 2.0
    target = np.array(b_principal["look_at"]["target"][:2])
    ways = [(eyes[name][:2] - target) / np.linalg.norm(eyes[name][:2] - target) for name in ("principal", "second")]
    assert np.degrees(np.arccos(np.dot(*ways))) > 150


def test_the_second_camera_sees_the_hidden_hand(across):
    start, end = _hold_times(across, "hidden_hand")
    (frame,) = simulate(across, frames=[int(round((start + end) / 2 * across.rate))])
    hand = [name for name, _ in across.labels()].index("worker/hand_right")
    assert np.count_nonzero(frame.label["principal"] == hand) == 0
    assert np.count_nonzero(frame.label["second"] == hand) > 200


@pytest.mark.parametrize("method", fw.FUSED_METHODS)
def test_fused_distances_never_exceed_the_truth(episode, allowed, method):
    reported, tolerance, _ = _method(episode, allowed, method, np.ones(len(episode.times), dtype=bool))
    # inf ("nothing within rho") is right when the truth is beyond rho: compare min(reported, rho).
    excess = np.minimum(reported, RHO) - (episode.truth + tolerance)
    assert np.all(excess <= 0), f"largest excess over truth + tolerance: {excess.max() * 1e3:.1f} mm"


def test_memory_only_clears(episode):
    """With the free-space memory, a fused distance is never below the one without it (memory only clears cells)."""
    without = episode.reported[episode.methods.index(fw.FUSED)]
    remembered = episode.reported[episode.methods.index(fw.FUSED_MEMORY)]
    assert np.all(remembered >= without - 1e-9)


def test_shadow_case_fusion_removes_only_what_a_camera_saw(episode, allowed):
    """A person between the principal camera and the robot, standing so near the principal camera that it measures
    nothing where the person is: that camera alone then counts everything in front of the robot as occupied and
    puts every point on the robot within about 0.1 m of it (false alarms), the end-effector inside it. Fused with the
    second camera, which sees the end-effector from the other side, no point is inside the shadow, and none is
    reported above the truth.

    The issue's "two cameras remove at least 90 % of the single camera's false alarms" fails here: the side of the
    links that faces the principal camera is hidden from the second camera by the links themselves, so no camera
    sees it and it stays occupied (docs/design.md, "Several cameras"; the closing note of issue 4). The 90 % holds where no
    robot hides anything: tests/test_judge_fusion.py."""
    rows = _case(episode, "shadow")
    truth = episode.truth[rows]
    principal, _, _ = _method(episode, allowed, episode.methods[0], rows)
    fused, tolerance, _ = _method(episode, allowed, fw.FUSED, rows)
    assert np.mean((principal < RHO) & (truth >= RHO)) >= 0.9  # the shadow's false alarms, else this proves nothing
    assert np.any(principal < 0.01)
    assert np.all(fused > 0.02), fused.min()
    assert np.all(np.minimum(fused, RHO) <= truth + tolerance)


def test_hidden_hand_case_fused_finds_the_hand(episode, allowed):
    """The hand behind the elbow as the principal camera sees it: the principal camera alone reports the control
    points near the hand farther than they are (flagged robot_blind_spot); fused with the second camera, not."""
    rows = _case(episode, "hidden_hand")
    truth = episode.truth[rows]
    principal, p_tolerance, p_flags = _method(episode, allowed, episode.methods[0], rows)
    fused, f_tolerance, _ = _method(episode, allowed, fw.FUSED, rows)
    near = truth < RHO
    hidden = near & (np.minimum(principal, RHO) > truth + p_tolerance)
    assert hidden.sum() >= FRAMES_PER_CASE  # the hand is hidden from the principal camera, at each frame
    assert np.all((p_flags[hidden] & int(dg.Flag.ROBOT_BLIND_SPOT)) != 0)
    assert np.all(fused[near] <= truth[near] + f_tolerance[near])


def _fake_episode():
    """Two control points, 8 frames at 1 Hz: frames 1-3 are the shadow case, 4-6 the hidden-hand case."""
    t = np.arange(8.0)
    far, near = 1.0, 0.2
    truth = np.array([[far, far]] * 4 + [[near, far]] * 4)
    inf = np.inf
    principal = np.array([[inf, inf], [0.1, 0.1], [0.1, 0.1], [0.1, inf], [0.3, inf], [inf, inf], [0.19, inf],
                          [inf, inf]])
    second = np.array([[inf, inf], [inf, inf], [inf, inf], [inf, 0.3], [0.2, inf], [0.2, inf], [0.2, inf],
                       [0.2, inf]])
    fused = np.array([[inf, inf], [inf, inf], [0.1, inf], [inf, inf], [0.2, inf], [0.19, inf], [0.2, inf],
                      [0.2, inf]])
    reported = np.stack([principal, second, fused, fused])
    flags = np.zeros(reported.shape, dtype=np.int64)
    flags[0, 4:7, 0] = int(dg.Flag.ROBOT_BLIND_SPOT)
    blind = np.full(reported.shape, np.inf)
    blind[0, 4:7, 0] = 0.15
    return fw.Episode(layout="fake", times=t, control_points=("a", "b"),
                      methods=("principal", "second") + fw.FUSED_METHODS,
                      eyes={"principal": np.zeros(3), "second": np.ones(3)}, truth=truth, reported=reported,
                      blind=blind, flags=flags, tolerance=np.full(reported.shape, 0.01),
                      spans=[("walk", 0.0, 1.0), ("shadow", 1.0, 4.0), ("hidden_hand", 4.0, 7.0)], seconds=1.0)


def test_summary_counts_on_a_hand_made_episode():
    layout = fw.summary([_fake_episode()])["layouts"]["fake"]
    principal, second, fused = (layout["methods"][m]["by_case"] for m in ("principal", "second", fw.FUSED))
    # Shadow (frames 1-3, truth far everywhere): the principal camera's 5 readings below rho are false alarms.
    assert principal["shadow"]["far_pairs"] == 6 and principal["shadow"]["false_alarms"] == 5
    assert second["shadow"]["false_alarms"] == 1 and fused["shadow"]["false_alarms"] == 1
    assert layout["false_alarms_removed"] == pytest.approx(1 - 1 / 5)
    assert layout["false_alarms_removed_with_memory"] == pytest.approx(1 - 1 / 5)
    # useful: of the 6 shadow pairs truly beyond rho + 5 cm, 5 reported below rho by the principal camera
    assert principal["shadow"]["useful_far_pairs"] == 6
    assert principal["shadow"]["useful_alarm_fraction"] == pytest.approx(5 / 6)
    # Hidden hand (frames 4-6, point a 0.2 m from the hand): the principal camera reports a at 0.3 and inf (misses,
    # flagged) and at 0.19 (right); inf for b, 1 m from everything, is right.
    assert principal["hidden_hand"]["misses"] == 2 and principal["hidden_hand"]["flagged_misses"] == 2
    assert principal["hidden_hand"]["unflagged_misses"] == 0
    assert fused["hidden_hand"]["misses"] == 0 and fused["hidden_hand"]["min_reported"] == pytest.approx(0.19)
    assert layout["methods"][fw.FUSED]["all_frames"]["misses"] == 0


def test_plots_and_the_command_line(tmp_path, capsys, monkeypatch):
    written = fw.plot(_fake_episode(), tmp_path)
    assert [p.name for p in written] == ["fake_shadow.png", "fake_hidden_hand.png"]
    assert all(p.stat().st_size > 5000 for p in written)

    from depthguard_lab import cli

    calls = []
    monkeypatch.setattr(fw, "main", lambda **kwargs: calls.append(kwargs) or 0)
    assert cli.main(["fusion-workcell", "--out", str(tmp_path), "--scene", "a.yaml", "--scene", "b.yaml",
                     "--all-frames"]) == 0
    assert calls == [dict(out=str(tmp_path), scenes=["a.yaml", "b.yaml"], all_frames=True)]
    monkeypatch.undo()
    assert cli.main(["fusion-workcell", "--out", str(tmp_path / "bad"), "--scene", str(tmp_path / "none.yaml")]) == 2
    assert "cannot read scene file" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_main_writes_plots_and_summary(tmp_path, capsys, across):
    # The first 0.2 s of a layout saved under another name (before either case: no plots): the file's name keys the
    # outputs.
    from depthguard_lab.simulation import save_workcell

    scene = tmp_path / "tiny.yaml"
    save_workcell(across, scene)
    assert fw.main(tmp_path, duration=0.2, scenes=[scene], progress=False) == 0
    assert "tiny:" in capsys.readouterr().out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["layouts"]["tiny"]["frames"] == 6


def test_the_packaged_layouts_differ_only_where_they_say():
    """scenario_b_four.yaml is scenario_b.yaml with two more cameras; scenario_b_four_tof.yaml is scenario_b_four.yaml
    with every camera's noise model lower (time-of-flight class), and nothing else."""
    from depthguard_lab.simulation import default_workcell

    paths = {p.name: p for p in fw.scene_paths(fw.SCENES + ("scenario_b_four_tof.yaml",))}
    reference, four, tof = (dict(load_workcell(paths[n]).scene) if n != "scenario_b.yaml" else
                            dict(default_workcell().scene) for n in ("scenario_b.yaml", "scenario_b_four.yaml",
                                                                     "scenario_b_four_tof.yaml"))
    ref_cams, four_cams, tof_cams = reference.pop("cameras"), four.pop("cameras"), tof.pop("cameras")
    assert reference == four == tof
    assert four_cams[:2] == ref_cams and [c["name"] for c in four_cams] == ["principal", "second", "third", "fourth"]
    for a, b in zip(four_cams, tof_cams):
        a, b = dict(a), dict(b)
        assert b.pop("noise") == {"a": 0.001, "b": 0.0, "c": 0.0005, "k": 3.0} != a.pop("noise")
        assert a == b


def test_the_three_camera_layout_is_scenario_b_with_the_suggested_camera():
    """scenario_b_three.yaml is scenario_b.yaml with one more camera of the principal's model, where `coverage
    --suggest` places it for scenario B's rig (probe_coverage_suggest.md: (-1.78, 1.18, 0.90)), and nothing else."""
    from depthguard_lab.simulation import default_workcell

    three = dict(load_workcell(fw.scene_paths(("scenario_b_three.yaml",))[0]).scene)
    reference = dict(default_workcell().scene)
    ref_cams, cams = reference.pop("cameras"), three.pop("cameras")
    assert three == reference
    assert cams[:2] == ref_cams and [c["name"] for c in cams] == ["principal", "second", "third"]
    third, principal = dict(cams[2]), dict(ref_cams[0])
    assert third.pop("look_at")["eye"] == [-1.78, 1.18, 0.90]
    for key in ("width", "height", "fx", "fy", "cx", "cy", "depth_range", "noise"):
        assert third[key] == principal[key]
