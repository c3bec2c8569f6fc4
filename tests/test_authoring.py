"""Authoring IKD targets (issue 26): AuthoringSession on the demo shot and the default head — the scripted acceptance
(pick the chin at 1.0 s, drag 3 mm down, solve, width 0.4 s, solve, undo, save: the file parses, keeps its comments
and reproduces the session's IKD result through run_shot), bad edits, undo/redo of every edit kind, warm starts that
reuse factorisations, cancel and progress."""

from __future__ import annotations

import shutil
import tomllib

import numpy as np
import pytest

from kdfaces.shots import AuthoringSession, load_shot, run_shot
from kdfaces.shots.builtin import DEMO_SHOT


def _chin(rig) -> int:
    """The lowest vertex of the front half of the jaw group (rest pose)."""
    from kdfaces.rig.groups import vertex_group

    jaw = vertex_group(rig, "jaw")
    z = rig.neutral[jaw, 2]
    front = jaw[z >= np.median(z)]
    return int(front[np.argmin(rig.neutral[front, 1])])


def _comments(text: str) -> list[str]:
    return [line[line.index("#"):] for line in text.splitlines() if "#" in line]


@pytest.fixture(scope="module")
def acceptance(tmp_path_factory):
    """The scripted session of the acceptance test, run once: (session, shot path, original text, results)."""
    folder = tmp_path_factory.mktemp("author")
    shot = folder / "demo.toml"
    shutil.copy(DEMO_SHOT, shot)
    original = shot.read_text()
    s = AuthoringSession(shot)
    chin = _chin(s.shot.rig)
    picked = s.add_point(1.0, chin)  # the handle appears at the chin's KD position at 1.0 s
    assert picked, s.status
    handle = s.handle(picked.row)
    assert np.allclose(handle, s.state(1.0)[chin])
    assert s.drag(picked.row, handle + np.array([0.0, -0.003, 0.0])), s.status
    first = s.solve()
    assert first is not None and first.converged, s.status
    after_first = s.result
    assert s.set_field(picked.row, "width_s", 0.4), s.status
    second = s.solve()
    assert second is not None and second.converged, s.status
    assert s.undo()
    saved = s.save()
    assert saved, s.status
    return dict(session=s, shot=shot, original=original, chin=chin, row=picked.row, first=first, second=second,
                after_first=after_first)


def test_acceptance_saved_file_parses_keeps_comments_and_reproduces_the_result(acceptance):
    s, shot = acceptance["session"], acceptance["shot"]
    text = shot.read_text()
    table = tomllib.loads(text)  # parses
    assert _comments(text) == _comments(acceptance["original"])  # every original comment, in order
    assert (shot.parent / "demo.toml.bak").read_text() == acceptance["original"]
    rows = table["constraints"]
    assert len(rows) == 5 and rows[-1]["group"] == [acceptance["chin"]] and rows[-1]["width_s"] == 0.25
    # the undo brought back the first solve's state (and its solution: nothing solved again)
    assert s.result is acceptance["after_first"] and not s.stale and not s.dirty
    run = run_shot(load_shot(shot))
    r, mine = run.ikd_result, s.result
    assert r.converged
    assert [c.label for c in r.constraints] == [c.label for c in mine.constraints]
    for a, b in zip(r.states, mine.states):
        assert np.abs(a - b).max() <= 1e-9  # the same IKD result through run_shot [m]
    assert np.abs(r.correction.values - mine.correction.values).max() <= 1e-9
    # the rows report what the solve did (mm; the velocity row in mm/s)
    tol_mm = 1e3 * s.options["tolerance_m"]
    point = s.rows[acceptance["row"]]
    assert point.status == "met" and point.error_after_mm <= tol_mm
    assert point.error_before_mm == pytest.approx(3.0, abs=1e-6)  # the drag: exactly 3 mm from the KD position
    assert point.gradient_ratio is not None and point.gradient_ratio > 0
    assert s.rows[3].unit == "mm/s"


def test_second_solve_was_warm_and_reused_the_lifts(acceptance):
    first, second = acceptance["first"], acceptance["second"]
    assert first.extra["lift_factorizations"] >= 1
    # the width edit changed the slots' bells (a new interpolation LU) but no lift (vertices and falloff unchanged)
    assert second.extra["lift_factorizations"] == 0 and second.extra["lu_factorizations"] == 1
    assert second.iterations <= first.iterations


@pytest.fixture()
def session(tmp_path):
    shot = tmp_path / "demo.toml"
    shutil.copy(DEMO_SHOT, shot)
    return AuthoringSession(shot)


def _unchanged(s, before_key, path, before_bytes):
    assert s._rows_key() == before_key
    assert path.read_bytes() == before_bytes


def test_bad_edits_give_a_message_and_change_nothing(session, tmp_path):
    s = session
    path = s.path
    disk = path.read_bytes()
    key = s._rows_key()
    chin = _chin(s.shot.rig)
    far = s.max_correction_m + 0.01
    # a target beyond max_correction_m
    o = s.drag(0, s.handle(0) + np.array([far, 0.0, 0.0]))
    assert not o and "max_correction_m" in o.message and s.status == o.message
    assert not s.add_point(1.0, chin, point_m=s.state(1.0)[chin] + [0.0, far, 0.0])
    # a time outside the shot
    o = s.add_point(s.end_s + 1.0, chin)
    assert not o and "outside the shot" in o.message
    assert not s.set_field(1, "time_s", s.start_s - 0.5)
    assert not s.add_velocity(s.start_s, "brows")  # t − h before the start
    # two pose constraints at one time
    o = s.add_pose(2.48, weights={"jawOpen": 0.5})
    assert not o and "pose" in o.message
    # values the schema rejects, rows that do not exist
    assert not s.set_field(0, "curve", "zigzag")
    assert not s.set_field(0, "width_s", -1.0)
    assert not s.set_field(9, "label", "x")
    assert not s.drag(3, [0.0, 0.0, 0.0])  # a velocity constraint has no handle
    assert not s.undo() and not s.can_undo  # nothing was applied
    _unchanged(s, key, path, disk)
    # saving onto a read-only path, into a read-only folder, over a file changed on disk
    assert s.set_field(0, "label", "jaw point")
    key = s._rows_key()
    path.chmod(0o444)
    o = s.save()
    assert not o and "read-only" in o.message
    path.chmod(0o644)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    assert not s.save(ro / "x.toml") and not (ro / "x.toml").exists()
    ro.chmod(0o755)
    path.write_bytes(disk + b"\n# edited elsewhere\n")
    o = s.save()
    assert not o and "changed on disk" in o.message
    _unchanged(s, key, path, disk + b"\n# edited elsewhere\n")
    assert not (tmp_path / "demo.toml.bak").exists()


def test_conflicts_and_unreachable_targets_say_why_in_their_rows(session):
    s = session
    # hold the jaw where the kinematic pose has it while the chin (jaw end effector) is sent 3 mm lower
    o = s.add_group(1.0, "jaw")
    assert o, s.status
    assert s.rows[0].status.startswith("conflicts with row 4") and s.rows[4].status.startswith("conflicts with row 0")
    assert s.solve() is None and "conflict" in s.status and s.result is None
    assert s.disable(4)
    assert not s.rows[0].status.startswith("conflict") and s.rows[4].status == "disabled"
    # out of reach: the solver may not correct by more than 1 mm, the chin wants 3
    s.options["max_correction_m"] = 0.001
    r = s.solve()
    assert r is not None and r.reason == "out_of_reach"
    assert s.rows[0].status.startswith("out of reach")
    assert s.rows[0].error_after_mm > 1e3 * s.options["tolerance_m"]


def test_undo_redo_every_edit_kind(session):
    s = session
    chin = _chin(s.shot.rig)
    edits = [
        lambda: s.add_point(1.0, chin),
        lambda: s.drag(4, s.handle(4) + [0.0, -0.002, 0.0]),
        lambda: s.set_offset_mm(4, [0.0, -1.0, 0.5]),
        lambda: s.add_group(4.0, "lips", label="lips hold"),
        lambda: s.add_pose(4.4, weights={"jawOpen": 0.3}, head_deg=[0.0, 5.0, 0.0]),
        lambda: s.add_velocity(4.8, "brows"),
        lambda: s.set_field(5, "time_s", 4.2),
        lambda: s.set_field(5, "width_s", 0.35),
        lambda: s.set_field(5, "curve", "poly"),
        lambda: s.set_field(5, "falloff_m", 0.03),
        lambda: s.set_field(5, "label", "renamed"),
        lambda: s.disable(2),
        lambda: s.enable(2),
        lambda: s.delete(1),
    ]
    for edit in edits:
        before = s._rows_key()
        o = edit()
        assert o, s.status
        after = s._rows_key()
        assert after != before
        assert s.undo() and s._rows_key() == before
        assert s.redo() and s._rows_key() == after
    assert s.rows[3].table["target"] == {"offset_m": [0.0, -0.001, 0.0005]}  # row 4 before the delete
    while s.can_undo:
        s.undo()
    assert not s.dirty and len(s.rows) == 4
    # an edit after an undo drops the redo history
    s.add_point(1.0, chin)
    s.undo()
    s.set_field(0, "label", "x")
    assert not s.can_redo


def test_bell_fields_are_shared_by_a_slot(session):
    s = session
    chin = _chin(s.shot.rig)
    o = s.add_point(1.0, chin)
    assert s.rows[o.row].width_s == s.rows[0].width_s == 0.25  # the new point takes the slot's bell
    assert s.set_field(o.row, "width_s", 0.4)
    assert s.rows[0].width_s == 0.4 and "also rows [0]" in s.status
    assert s.set_field(o.row, "time_s", 2.48)  # moved onto the pose's slot: takes its width
    assert s.rows[o.row].width_s == 0.3 and s.rows[0].width_s == 0.4


def test_warm_start_reuses_lifts_lu_and_models_and_refactors_what_changed(session):
    s = session
    assert s.solve() is not None
    h = s.handle(0)
    assert s.drag(0, h + [0.0, -0.001, 0.0])
    r = s.solve()
    assert r.converged
    assert r.extra["lift_factorizations"] == 0 and r.extra["lu_factorizations"] == 0
    assert r.extra["models_reused"] >= 1
    # a changed falloff is a new lift (factorised once when first used, never a stale one) and a new secant model
    assert s.set_field(0, "falloff_m", 0.04)
    assert s.drag(0, h + [0.0, 0.001, 0.0])
    r2 = s.solve()
    assert r2.converged and r2.extra["lift_factorizations"] == 1
    assert r2.extra["models_reused"] == len(r2.constraints) - 1
    assert r2.constraints[0].falloff_m == 0.04


def test_cancel_and_progress(session):
    s = session
    seen = []
    r = s.solve(cancel=lambda: True)
    assert r is None and "cancelled" in s.status and s.result is None
    r = s.solve(progress=lambda k, n, err: seen.append((k, n, err.shape)))
    assert r is not None and seen and seen[0][1] == s.options["max_iterations"] and seen[0][2] == (4,)


def test_disabled_rows_are_saved_and_skipped_by_run(session):
    s = session
    assert s.disable(2)
    assert s.save()
    data = tomllib.loads(s.path.read_text())
    assert data["constraints"][2]["enabled"] is False
    shot = load_shot(s.path)
    assert [c.label for c in shot.constraints()] == ["chin", "tilted smile", "brows velocity"]
    again = AuthoringSession(s.path)
    assert [r.enabled for r in again.rows] == [True, True, False, True]
    assert again.enable(2) and again.save()
    assert "enabled" not in tomllib.loads(s.path.read_text())["constraints"][2]


def test_deleting_a_row_keeps_the_other_tables(session):
    s = session
    original = s.path.read_text()
    assert s.delete(1) and s.save()
    text = s.path.read_text()
    data = tomllib.loads(text)
    assert [c["label"] for c in data["constraints"]] == ["chin", "lips", "brows velocity"]
    assert "# The chin lands 3 mm lower right after the head turn stops." in text
    assert text.split("[solver]")[1] == original.split("[solver]")[1]
