"""Issue 10, point 3: disk faults. A full disk, a quota, a read-only or forbidden folder at any write (dataset
records and manifest, pictures, the object cache) is one ``ges: error:`` line naming the path, the cause and
what to do; a failed write leaves no partial file; a picture that cannot be written never costs its record.

Faults are simulated where the OS reports them (``os.open``/``os.mkdir`` refuse with EROFS or EACCES, ``os.fsync``
with ENOSPC or EDQUOT, for paths under one folder): the tests run as root here, where ``chmod`` blocks nothing.
Where a tmpfs can be mounted (root with the capability), two more probes use a real full and a real read-only one.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
from pathlib import Path

import pytest
from test_dataset import CONFIG, make_record

from ges_core import cli
from ges_core.dataset import DatasetWriter, open_dataset, validate_dataset
from ges_core.errors import StorageError
from ges_core.paths import CACHE_ENV, atomic_write_bytes

FULL = (errno.ENOSPC, errno.EDQUOT)
DENIED = (errno.EROFS, errno.EACCES)
CAUSES = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
}
SYNTH = ["--hands", "allegro", "--sim", "pybullet", "--no-progress", "-o", "validate.hold_steps=60"]
"""The quickest real ``ges synth`` (PyBullet, short hold)."""


@pytest.fixture
def fault(monkeypatch):
    """``fault(folder, code)``: from now on, writes under ``folder`` fail with errno ``code`` as the OS reports it
    (creating or opening for writing: EROFS/EACCES; flushing to disk: ENOSPC/EDQUOT)."""

    def under(path) -> bool:
        real = os.path.realpath(os.fspath(path))
        return real == root[0] or real.startswith(root[0] + os.sep)

    root = [""]

    def install(folder: Path, code: int) -> None:
        root[0] = os.path.realpath(folder)
        real_open, real_mkdir, real_fsync = os.open, os.mkdir, os.fsync

        def refuse(path):
            raise OSError(code, os.strerror(code), os.fspath(path))

        def fsync(fd):
            if under(os.readlink(f"/proc/self/fd/{fd}")):
                raise OSError(code, os.strerror(code))
            return real_fsync(fd)

        def open_(path, flags, *args, **kwargs):
            if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT) and under(path):
                refuse(path)
            return real_open(path, flags, *args, **kwargs)

        def mkdir(path, *args, **kwargs):
            if under(path) and not os.path.isdir(path):
                refuse(path)
            return real_mkdir(path, *args, **kwargs)

        if code in FULL:
            monkeypatch.setattr(os, "fsync", fsync)
        else:
            monkeypatch.setattr(os, "open", open_)
            monkeypatch.setattr(os, "mkdir", mkdir)

    return install


def one_error_line(err: str) -> str:
    assert err.count("\n") == 1 and err.startswith("ges: error: ") and "Traceback" not in err, err
    return err.removeprefix("ges: error: ").strip()


# -- the writers ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("code", FULL + DENIED, ids=errno.errorcode.get)
def test_a_failed_write_is_one_storage_error_and_leaves_no_partial_file(tmp_path, fault, code):
    target = tmp_path / "out" / "file.bin"
    atomic_write_bytes(target, b"old")
    fault(tmp_path / "out", code)
    with pytest.raises(StorageError) as info:
        atomic_write_bytes(target, b"new")
    assert str(info.value).startswith(f"{CAUSES[code]} writing {target}; ")
    assert info.value.errno == code and info.value.filename == str(target) and isinstance(info.value, OSError)
    assert target.read_bytes() == b"old" and sorted(p.name for p in target.parent.iterdir()) == ["file.bin"]


@pytest.mark.parametrize("code", FULL, ids=errno.errorcode.get)
def test_a_full_disk_while_adding_records_keeps_every_record_written_before(tmp_path, fault, code):
    root = tmp_path / "ds"
    writer = DatasetWriter(root, CONFIG, manifest_interval=0)
    writer.add(make_record("procedural/box/000"))
    fault(root, code)
    with pytest.raises(StorageError, match=rf"^{CAUSES[code]} writing {root}/records/shadow/procedural__mug__001-"):
        writer.add(make_record("procedural/mug/001"))
    with pytest.raises(StorageError, match=r"procedural__can__002-.*; free space there or write to another folder$"):
        writer.add(make_record("procedural/can/002"))
    del writer
    assert not list(root.rglob("*.tmp")) and validate_dataset(root) == []
    assert [e["object_id"] for e in open_dataset(root).entries] == ["procedural/box/000"]


@pytest.mark.parametrize("code", DENIED, ids=errno.errorcode.get)
def test_a_read_only_output_folder_is_refused_at_open(tmp_path, fault, code):
    fault(tmp_path, code)
    with pytest.raises(StorageError, match=rf"^{CAUSES[code]} writing {tmp_path / 'ds'}; .*another folder"):
        DatasetWriter(tmp_path / "ds", CONFIG)


def test_a_full_disk_at_the_manifest_on_close_keeps_the_records(tmp_path, fault):
    root = tmp_path / "ds"
    full = pytest.raises(StorageError, match=r"^no space left on device writing .*manifest\.json")
    with full, DatasetWriter(root, CONFIG, manifest_interval=3600) as writer:
        writer.add(make_record("procedural/box/000"))
        fault(root, errno.ENOSPC)
    assert len(open_dataset(root)) == 1 and not (root / ".lock").exists()


# -- the command line --------------------------------------------------------------------------------------


@pytest.mark.parametrize("code", DENIED, ids=errno.errorcode.get)
def test_ges_synth_into_a_read_only_folder_is_one_error_line(tmp_path, fault, capsys, code):
    out = tmp_path / "runs" / "x"
    fault(tmp_path / "runs", code)
    assert cli.main(["synth", "--objects", "procedural/box/000", *SYNTH, "--out", str(out)]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line == f"{CAUSES[code]} writing {out}; make it writable or write to another folder"


@pytest.mark.sim
@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS], ids=errno.errorcode.get)
def test_ges_synth_with_a_full_or_read_only_cache_is_one_error_line(tmp_path, fault, capsys, monkeypatch, code):
    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV, str(cache))
    fault(cache, code)
    assert cli.main(["synth", "--objects", "procedural/box/000", *SYNTH, "--out", str(tmp_path / "ds")]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith(f"{CAUSES[code]} writing {cache}") and f"set {CACHE_ENV} to" in line, line


def test_an_os_error_outside_the_writers_is_one_error_line(tmp_path, monkeypatch, capsys):
    """The CLI's last resort: an OSError no writer turned into a StorageError (here from ``ges dataset info``)."""
    import ges_core.dataset as dataset

    def broken(path):
        raise PermissionError(errno.EACCES, "Permission denied", str(path / "manifest.json"))

    monkeypatch.setattr(dataset, "open_dataset", broken)
    assert cli.main(["dataset", "info", str(tmp_path)]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line == f"permission denied at {tmp_path / 'manifest.json'}; check its permissions"


# -- pictures -----------------------------------------------------------------------------------------------


@pytest.mark.sim
def test_pictures_into_a_read_only_folder_keep_the_records(tmp_path, fault, capsys, caplog):
    """The issue's probe: the grasp was computed, the picture failed, and the record was lost with it."""
    pictures = tmp_path / "pictures"
    fault(pictures, errno.EROFS)
    objects = ["procedural/box/000", "procedural/cube/000"]
    argv = ["synth", "--objects", *objects, *SYNTH, "--out", str(tmp_path / "ds"), "--pictures", str(pictures)]
    assert cli.main(argv) == 0, capsys.readouterr().err
    records = {r.object_id: r for r in open_dataset(tmp_path / "ds")}
    assert sorted(records) == objects and validate_dataset(tmp_path / "ds") == []
    for oid, record in records.items():
        assert record.picture is None and record.grasp is not None
        expected = f"read-only file system writing {pictures / 'allegro' / oid.replace('/', '__')}.png; make it"
        assert record.errors["picture"].startswith(expected), record.errors
    warnings = [r.getMessage() for r in caplog.records if "pictures" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith("ges: warning: read-only file system writing"), warnings


# -- real file systems (root with the mount capability only) ------------------------------------------------


@pytest.fixture
def tmpfs(tmp_path):
    """A 256 KiB tmpfs mounted at ``tmp_path / "mnt"``; skipped where mounting is not allowed."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_a_real_full_disk(tmpfs):
    root, added = tmpfs / "ds", []
    writer = DatasetWriter(root, CONFIG, manifest_interval=3600)
    with pytest.raises(StorageError, match=r"^no space left on device writing .*; free space"):
        for i in range(1000):
            writer.add(make_record(f"procedural/box/{i:03d}", seed=i))
            added.append(f"procedural/box/{i:03d}")
    del writer
    assert 5 < len(added) < 1000 and not list(root.rglob("*.tmp"))
    stored = sorted(e["object_id"] for e in open_dataset(root).entries)
    assert stored[: len(added)] == added and len(stored) <= len(added) + 1  # + one whose timing file did not fit


def test_a_real_read_only_file_system(tmpfs, capsys):
    with DatasetWriter(tmpfs / "ds", CONFIG) as writer:
        writer.add(make_record("procedural/box/000"))
    manifest = (tmpfs / "ds" / "manifest.json").read_text()
    subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)], check=True)
    with pytest.raises(StorageError, match=rf"^read-only file system writing {tmpfs / 'ds'}/\.lock; make it writable"):
        DatasetWriter(tmpfs / "ds", CONFIG)
    argv = ["synth", "--objects", "procedural/box/000", *SYNTH, "--out", str(tmpfs / "new")]
    assert cli.main(argv) == 1
    assert one_error_line(capsys.readouterr().err).startswith(f"read-only file system writing {tmpfs / 'new'}")
    assert (tmpfs / "ds" / "manifest.json").read_text() == manifest and len(open_dataset(tmpfs / "ds")) == 1
    assert json.loads(manifest)["records"][0]["object_id"] == "procedural/box/000"
