import pytest

from aril_ros.files import write_atomically


def test_a_file_is_replaced_whole_or_left_as_it_was(tmp_path):
    path = tmp_path / "state.json"
    path.write_text("old")

    def fails(partial):
        partial.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomically(path, fails)
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]
    seen = []
    assert write_atomically(path, lambda partial: seen.append(partial.name) or partial.write_text("new")) == path
    assert path.read_text() == "new" and seen[0].endswith(".partial") and not (tmp_path / seen[0]).exists()
