"""Checkpoint arrays streamed into their zip entries (docs/decisions.md 108): the entries are
those of an npz written from memory, and a write that fails leaves the file as it was."""

from __future__ import annotations

import errno
import io
import lzma
import zipfile

import numpy as np
import pytest

from qlap_runtime.qlap.checkpoint import files as checkpoint_files
from qlap_runtime.qlap.checkpoint.files import ROWS, read_npz, write_npz


def npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a, allow_pickle=False)
    return buf.getvalue()


ARRAYS = {ROWS: np.linspace(-1.0, 1.0, 60_000).reshape(-1, 6),      # an xz entry
          "counts": np.arange(100_000, dtype=np.int64) % 7,          # deflated
          "empty": np.zeros(0), "flags": np.array([True, False, True])}


def test_streamed_entries_are_the_arrays_deflated_or_xz_as_before(tmp_path):
    path = tmp_path / "a.npz"
    write_npz(path, ARRAYS)
    with zipfile.ZipFile(path) as zf:
        infos = {i.filename: i for i in zf.infolist()}
        assert sorted(infos) == sorted(["_rows.npy.xz", "counts.npy", "empty.npy",
                                        "flags.npy"])
        raw = npy_bytes(ARRAYS[ROWS])
        assert infos["_rows.npy.xz"].compress_type == zipfile.ZIP_STORED
        assert zf.read("_rows.npy.xz") == lzma.compress(raw, preset=0)   # one-shot, as before
        assert infos["counts.npy"].compress_type == zipfile.ZIP_DEFLATED
        assert zf.read("counts.npy") == npy_bytes(ARRAYS["counts"])
        assert infos["counts.npy"].compress_size < infos["counts.npy"].file_size / 10
    back = read_npz(path)
    for key, a in ARRAYS.items():
        np.testing.assert_array_equal(back[key], a)
        assert back[key].dtype == a.dtype
    write_npz(tmp_path / "fast.npz", ARRAYS, fast=True)
    with zipfile.ZipFile(tmp_path / "fast.npz") as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_STORED}
        assert zf.read("_rows.npy") == npy_bytes(ARRAYS[ROWS])


def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary(tmp_path,
                                                                        monkeypatch):
    path = tmp_path / "a.npz"
    write_npz(path, {"old": np.arange(3)})
    before = path.read_bytes()
    real = np.lib.format.write_array
    calls = []

    def full_disk(fp, array, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fp, array, **kw)

    monkeypatch.setattr(checkpoint_files.np.lib.format, "write_array", full_disk)
    with pytest.raises(OSError, match="No space left"):
        write_npz(path, ARRAYS)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]
