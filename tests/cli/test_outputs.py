"""What the commands write appears whole or not at all, and a missing output folder is refused before the work."""
import json
import os

import numpy as np
import pytest

from skinkit import SkinkitError
from skinkit.cli import main
from skinkit.cli.outputs import written_atomically
from skinkit.meshio import write_obj


def test_a_file_appears_only_once_complete(tmp_path):
    target = tmp_path / "out.obj"
    with written_atomically(str(target)) as temporary:
        assert temporary.endswith(".obj") and os.path.dirname(temporary) == str(tmp_path)
        with open(temporary, "w") as file:
            file.write("v 0 0 0\n")
        assert not target.exists()
    assert target.read_text() == "v 0 0 0\n"
    assert os.listdir(tmp_path) == ["out.obj"]


def test_a_failed_write_leaves_neither_file_nor_temporary(tmp_path):
    target = tmp_path / "out.obj"
    target.write_text("the previous result\n")
    with pytest.raises(RuntimeError):
        with written_atomically(str(target)) as temporary:
            with open(temporary, "w") as file:
                file.write("half")
            raise RuntimeError("killed midway")
    assert target.read_text() == "the previous result\n"
    assert os.listdir(tmp_path) == ["out.obj"]


def test_an_output_in_a_missing_folder_is_refused_before_any_work(tmp_path, capsys):
    mesh = tmp_path / "mesh.obj"
    write_obj(str(mesh), np.eye(3), np.array([[0, 1, 2]]))
    missing = tmp_path / "no" / "such" / "atlas.obj"
    assert main(["unwrap", str(mesh), "--out", str(missing), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert "the folder" in report["error"] and "does not exist" in report["error"]
    with pytest.raises(SkinkitError, match="does not exist"):
        with written_atomically(str(missing)):
            pass
