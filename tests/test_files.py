"""Package files and atomic writes (``files.py``)."""

import os

import pytest

from cartpole_warp.settings.files import atomic_write


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    target = tmp_path / "model_3.pt"
    target.write_text("complete")

    def crash(tmp):
        with open(tmp, "w") as f:
            f.write("half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        atomic_write(target, crash)
    assert target.read_text() == "complete" and os.listdir(tmp_path) == ["model_3.pt"]
