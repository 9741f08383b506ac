"""Issue 18: where two inputs meant to be one mesh disagree in units (an FBX in centimetres beside an Alembic in
metres: 100x), every command says so in the same words (skinkit._checks.units_sentence) and refuses."""
import numpy as np
import pytest
from tests.cli.obj_folders import write_obj_folder
from tests.cli.test_cli import skinkit
from tests.core.test_unwrap import capsule
from tests.sequences import rigid_chain_sequence

from skinkit import SkinkitError
from skinkit._checks import units_sentence
from skinkit.fit import check_vertex_order
from skinkit.meshio import write_obj

#: The part of the sentence every command shares, whatever it names and however it says to mend it.
SHARED = units_sentence("X", 100.0, "Y").split("Y", 1)[1]


def test_the_sentence_names_both_inputs_the_ratio_and_the_cause():
    sentence = units_sentence("example 3", 0.01, "the rest mesh", "scale one")
    assert sentence == ("example 3 is 0.01 times the size of the rest mesh: the files use different units or scales; "
                        "scale one")
    assert SHARED == ": the files use different units or scales"


def test_unwrap_refuses_a_sequence_in_other_units(tmp_path):
    positions, triangles = capsule()
    mesh = tmp_path / "capsule.obj"
    write_obj(str(mesh), positions, triangles)
    (tmp_path / "frames").mkdir()
    folder = write_obj_folder(tmp_path / "frames", np.stack([positions] * 3), triangles)  # in centimetres
    status, report = skinkit("unwrap", str(mesh), "--sequence", folder, "--out", str(tmp_path / "a.obj"), "--json",
                             expect_success=False)
    assert status == 1
    assert f"--sequence frame 0 is 100 times the size of the mesh of {mesh}{SHARED}" in report["error"]


def test_decompose_refuses_a_rest_mesh_in_other_units(tmp_path):
    frames, triangles, _, _ = rigid_chain_sequence(segments=2, frames=4)
    (tmp_path / "frames").mkdir()
    folder = write_obj_folder(tmp_path / "frames", frames, triangles)  # in centimetres, the rest in metres
    rest = tmp_path / "rest.obj"
    write_obj(str(rest), frames[0], triangles)
    status, report = skinkit("decompose", "--sequence", folder, "--rest", str(rest), "--json", expect_success=False)
    assert status == 1
    assert f"--sequence frame 0 is 100 times the size of --rest {rest}{SHARED}" in report["error"]
    assert "--sequence-scale" in report["error"]


def test_fit_refuses_examples_in_other_units():
    frames, triangles, _, _ = rigid_chain_sequence(segments=2, frames=3)
    with pytest.raises(SkinkitError, match=f"example 0 is 0.01 times the size of the rest mesh{SHARED}"):
        check_vertex_order(frames[0], frames * 0.01, triangles)
    check_vertex_order(frames[0], frames * 1.5, triangles)  # a pose or a small scale change is not a unit change
