from __future__ import annotations

from pathlib import Path

import pytest

from cam2sim.core.files import atomic_folder, file_fingerprint, write_text_atomic


def test_write_text_atomic_replaces_the_whole_file(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "a.txt"
    write_text_atomic(path, "one")
    write_text_atomic(path, "two")
    assert path.read_text() == "two"
    assert [p.name for p in path.parent.iterdir()] == ["a.txt"]


def test_atomic_folder_swaps_in_the_new_content(tmp_path: Path) -> None:
    target = tmp_path / "dataset"
    with atomic_folder(target) as tmp:
        (tmp / "old.txt").write_text("old")
    with atomic_folder(target) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == ["new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dataset"]


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_atomic_folder_keeps_the_old_content_on_failure(tmp_path: Path, exc: type) -> None:
    target = tmp_path / "dataset"
    with atomic_folder(target) as tmp:
        (tmp / "old.txt").write_text("old")

    def build() -> None:
        with atomic_folder(target) as tmp:
            (tmp / "half.txt").write_text("half")
            raise exc

    with pytest.raises(exc):
        build()
    assert sorted(p.name for p in target.iterdir()) == ["old.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dataset"]


def test_fingerprint_changes_when_a_file_is_truncated_or_changed(tmp_path: Path) -> None:
    path = tmp_path / "big.bin"
    path.write_bytes(bytes(range(256)) * 20000)
    a = file_fingerprint(path)
    assert file_fingerprint(path) == a
    path.write_bytes(bytes(range(256)) * 19999)
    b = file_fingerprint(path)
    data = bytearray(bytes(range(256)) * 19999)
    data[-1] ^= 1
    path.write_bytes(bytes(data))
    assert len({a, b, file_fingerprint(path)}) == 3


def test_read_json_names_the_file_the_place_and_the_fix(tmp_path: Path) -> None:
    from cam2sim.core.errors import WorkspaceError
    from cam2sim.core.files import read_json

    path = tmp_path / "run.json"
    path.write_text('{"kind": "drive", "steps": 3}', encoding="utf-8")
    assert read_json(path) == {"kind": "drive", "steps": 3}
    path.write_text('{"kind": "dri', encoding="utf-8")  # a crash mid-write by another tool
    with pytest.raises(
        WorkspaceError, match=r"run\.json is not valid JSON \(.*char.*\); drive again"
    ):
        read_json(path, fix="drive again")
    with pytest.raises(WorkspaceError, match=r"nope\.json does not exist; make it"):
        read_json(tmp_path / "nope.json", fix="make it")
    path.write_bytes(b"\xff\xfe{")
    with pytest.raises(WorkspaceError, match="not valid JSON"):
        read_json(path)


def test_atomic_writes_get_the_permissions_of_a_plain_open(tmp_path: Path) -> None:
    import stat

    plain = tmp_path / "plain.txt"
    plain.write_text("x", encoding="utf-8")
    atomic = tmp_path / "atomic.txt"
    write_text_atomic(atomic, "x")
    mode = stat.S_IMODE(atomic.stat().st_mode)
    assert mode == stat.S_IMODE(plain.stat().st_mode)  # a shared report, not 0600
