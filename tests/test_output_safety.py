"""No command removes or changes a file it did not write: every command that takes ``--out`` is pointed at a folder
holding a user's file, at the working folder and at a file, and must refuse in one line (exit 2) before any work,
leaving the user's bytes as they were. An earlier run's folder is replaced only while it holds nothing but what that
run wrote (its manifest), and a killed run's hidden leftovers are cleaned by the next run on the same ``--out``."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from kdfaces.cli import main as kdfaces_main
from kdfaces.io.atomic import MANIFEST_NAME, OutputFolder, check_output_folder
from kdfem.cli import main as kdfem_main

DEMO = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"
USER_BYTES = b"the user's own notes\n"

# every verb with --out, as (entry point, argv before --out)
COMMANDS = [
    ("kdfaces", ["demo"]),
    ("kdfaces", ["run", str(DEMO)]),
    ("kdfaces", ["bake", str(DEMO), "--workers", "1"]),
    ("kdfaces", ["render", str(DEMO)]),
    ("kdfaces", ["export-rig"]),
    ("kdfaces", ["punch"]),
    ("kdfem", ["demo"]),
    ("kdfem", ["window"]),
    ("kdfem", ["door"]),
    ("kdfem", ["follow"]),
]
MAIN = {"kdfaces": kdfaces_main, "kdfem": kdfem_main}


def _refused(capsys, prog, argv, out, expect: str):
    t0 = time.perf_counter()
    rc = MAIN[prog]([*argv, "--out", str(out)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc == 2, err
    assert len(lines) == 1 and "Traceback" not in err, lines
    assert expect in lines[0], lines[0]
    assert time.perf_counter() - t0 < 30  # refused before any computation


@pytest.mark.parametrize("prog, argv", COMMANDS, ids=[" ".join([p, a[0]]) for p, a in COMMANDS])
def test_out_never_replaces_a_users_folder_the_working_folder_or_a_file(tmp_path, capsys, monkeypatch, prog, argv):
    # a user's folder
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_bytes(USER_BYTES)
    _refused(capsys, prog, argv, mine, "did not write (it holds 'notes.txt')")
    assert sorted(os.listdir(mine)) == ["notes.txt"] and (mine / "notes.txt").read_bytes() == USER_BYTES
    # the working folder
    work = tmp_path / "work"
    work.mkdir()
    (work / "take.csv").write_bytes(USER_BYTES)
    monkeypatch.chdir(work)
    _refused(capsys, prog, argv, ".", "is the working folder")
    _refused(capsys, prog, argv, "..", "holds it")
    monkeypatch.chdir(tmp_path)
    assert sorted(os.listdir(work)) == ["take.csv"] and (work / "take.csv").read_bytes() == USER_BYTES
    # a file
    f = tmp_path / "result.txt"
    f.write_bytes(USER_BYTES)
    _refused(capsys, prog, argv, f, "exists and is not a folder")
    assert f.read_bytes() == USER_BYTES
    # nothing was left beside them
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine", "result.txt", "work"]


def test_an_earlier_output_is_replaced_only_while_it_holds_only_what_it_wrote(tmp_path, capsys):
    out = tmp_path / "rig"
    argv = ["export-rig", "--format", "obj", "--out", str(out)]
    assert kdfaces_main(argv) == 0
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert manifest["written_by"] == "kdfaces" and "summary.json" in manifest["files"]
    assert all((out / f).is_file() for f in manifest["files"])
    assert kdfaces_main(argv) == 0  # a rerun replaces its own folder
    (out / "obj").joinpath("my-edit.obj").write_bytes(USER_BYTES)  # the user adds a file inside it
    capsys.readouterr()
    assert kdfaces_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "also holds 'obj/my-edit.obj'" in err and len(err.splitlines()) == 1
    assert (out / "obj" / "my-edit.obj").read_bytes() == USER_BYTES
    # an empty folder is taken
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_output_folder(empty) == empty.absolute()
    # a manifest that is not ours does not make a user's folder replaceable
    forged = tmp_path / "forged"
    forged.mkdir()
    (forged / MANIFEST_NAME).write_text("{}")
    (forged / "a.txt").write_bytes(USER_BYTES)
    with pytest.raises(Exception, match="did not write"):
        check_output_folder(forged)


def test_a_killed_runs_hidden_folders_are_removed_by_the_next_run(tmp_path):
    out = tmp_path / "out"
    dead = 2 ** 22 + 12345  # above the default pid_max: no process has it
    stale = tmp_path / f".out.partial-{dead}-abcd"
    stale.mkdir()
    (stale / "half.pc2").write_bytes(b"x")
    stale_old = tmp_path / f".out.old-{dead}-efgh"
    stale_old.mkdir()
    live = tmp_path / f".out.partial-{os.getpid()}-live"  # a run that still works (this process)
    live.mkdir()
    with OutputFolder(out) as tmp:
        (tmp / "a.txt").write_text("a")
    assert not stale.exists() and not stale_old.exists() and live.is_dir()
    assert (out / "a.txt").read_text() == "a"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f".out.partial-{os.getpid()}-live", "out"])


def test_a_link_is_never_replaced(tmp_path):
    target = tmp_path / "target"
    target.mkdir()
    (target / "keep.txt").write_bytes(USER_BYTES)
    link = tmp_path / "link"
    link.symlink_to(target)
    with pytest.raises(Exception, match="symbolic link"):
        check_output_folder(link)
    assert (target / "keep.txt").read_bytes() == USER_BYTES


def test_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    import errno

    import kdfaces.io.summary as summary

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "out" / "summary.json"))

    monkeypatch.setattr(summary, "write_summary", full)
    out = tmp_path / "out"
    assert kdfaces_main(["export-rig", "--format", "obj", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "No space left on device" in lines[0] and "Traceback" not in err, lines
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_failed_run_removes_the_parent_folders_it_created(tmp_path, capsys, monkeypatch):
    """``kd-out/`` made for a default ``--out`` goes again when the run fails; a parent that holds something else
    (or existed before) stays."""
    monkeypatch.chdir(tmp_path)
    assert kdfaces_main(["punch", "--screenshot", "x.png"]) == 2  # refused after the output folder was set up
    assert "only with --view" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    folder = OutputFolder(tmp_path / "a" / "b" / "out")
    folder.__enter__()
    (tmp_path / "a" / "kept.txt").write_bytes(USER_BYTES)  # something else writes beside it meanwhile
    folder.abandon()
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "kept.txt"]
    assert (tmp_path / "a" / "kept.txt").read_bytes() == USER_BYTES
