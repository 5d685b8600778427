"""atomic_write / atomic_dir: all or nothing, never debris."""

from __future__ import annotations

import os
import stat

import pytest

from fmu_greybox import atomic
from fmu_greybox.atomic import atomic_dir, atomic_write


class BoomError(Exception):
    pass


def test_atomic_write_text_and_binary(tmp_path):
    with atomic_write(tmp_path / "a.txt") as handle:
        handle.write("héllo\n")
    with atomic_write(tmp_path / "b.bin", "wb") as handle:
        handle.write(b"\x00\x01")
    assert (tmp_path / "a.txt").read_text(encoding="utf-8") == "héllo\n"
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    assert sorted(os.listdir(tmp_path)) == ["a.txt", "b.bin"]


def test_atomic_write_replaces_existing_file(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with atomic_write(target) as handle:
        handle.write("new")
        assert target.read_text() == "old"  # not visible until the block ends
    assert target.read_text() == "new"
    assert os.listdir(tmp_path) == ["a.txt"]


def test_atomic_write_failure_keeps_previous_file_and_leaves_no_debris(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(BoomError), atomic_write(target) as handle:
        handle.write("half")
        raise BoomError
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["a.txt"]


def test_atomic_write_failure_without_previous_file_leaves_nothing(tmp_path):
    with pytest.raises(BoomError), atomic_write(tmp_path / "a.bin", "wb"):
        raise BoomError
    assert os.listdir(tmp_path) == []


def test_atomic_write_honours_umask(tmp_path):
    old = os.umask(0o027)
    try:
        with atomic_write(tmp_path / "a.txt") as handle:
            handle.write("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o640


def test_atomic_write_rejects_other_modes(tmp_path):
    with pytest.raises(ValueError, match="mode"), atomic_write(tmp_path / "a.txt", "a"):
        pass
    assert os.listdir(tmp_path) == []


def test_atomic_dir_creates_and_replaces(tmp_path):
    target = tmp_path / "model"
    with atomic_dir(target) as build:
        (build / "a.json").write_text("1")
        assert not target.exists()
    assert os.listdir(target) == ["a.json"]
    with atomic_dir(target) as build:
        (build / "b.json").write_text("2")
    assert os.listdir(target) == ["b.json"]
    assert os.listdir(tmp_path) == ["model"]


def test_atomic_dir_failure_keeps_previous_dir_and_leaves_no_debris(tmp_path):
    target = tmp_path / "model"
    target.mkdir()
    (target / "a.json").write_text("old")
    with pytest.raises(BoomError), atomic_dir(target) as build:
        (build / "a.json").write_text("half")
        (build / "sub").mkdir()
        raise BoomError
    assert (target / "a.json").read_text() == "old"
    assert os.listdir(target) == ["a.json"]
    assert os.listdir(tmp_path) == ["model"]


def test_atomic_dir_failure_without_previous_dir_leaves_nothing(tmp_path):
    with pytest.raises(BoomError), atomic_dir(tmp_path / "model"):
        raise BoomError
    assert os.listdir(tmp_path) == []


def test_atomic_dir_failed_swap_restores_previous_dir(tmp_path, monkeypatch):
    target = tmp_path / "model"
    target.mkdir()
    (target / "a.json").write_text("old")
    real_replace = os.replace
    calls = []

    def flaky_replace(src, dst):
        calls.append((src, dst))
        if len(calls) == 2:  # moving the new directory into place
            raise OSError("disk on fire")
        real_replace(src, dst)

    monkeypatch.setattr(atomic.os, "replace", flaky_replace)
    with pytest.raises(OSError, match="disk on fire"), atomic_dir(target) as build:
        (build / "a.json").write_text("new")
    assert (target / "a.json").read_text() == "old"
    assert os.listdir(tmp_path) == ["model"]


def test_atomic_dir_refuses_a_file(tmp_path):
    (tmp_path / "model").write_text("x")
    with pytest.raises(NotADirectoryError), atomic_dir(tmp_path / "model"):
        pass
    assert (tmp_path / "model").read_text() == "x"
