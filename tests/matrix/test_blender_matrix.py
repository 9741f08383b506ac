"""The Blender matrix's environments: requirements-dev.txt with each release's bpy pinned, cached by their hash."""
import os

import pytest

from tests.matrix import blender_matrix


def test_each_release_pins_its_own_bpy_and_keeps_the_other_pins():
    with open(os.path.join(blender_matrix.ROOT, "requirements-dev.txt")) as file:
        development = file.read()
    for release in blender_matrix.BLENDER_RELEASES:
        requirements = blender_matrix.requirements_for(release)
        assert f"bpy=={release}\n" in requirements and requirements.count("bpy==") == 1
        assert requirements.replace(f"bpy=={release}", "") == blender_matrix.PIN.sub("", development)


def test_environments_are_named_by_series_and_requirement_hash():
    first = blender_matrix.environment_path("4.2.23", "bpy==4.2.23\nnumpy==1.26.4\n")
    assert os.path.basename(first).startswith(".venv-bpy-4.2-")
    assert first == blender_matrix.environment_path("4.2.23", "bpy==4.2.23\nnumpy==1.26.4\n")
    assert first != blender_matrix.environment_path("4.2.23", "bpy==4.2.23\nnumpy==1.26.3\n")


def test_the_releases_cover_every_series_the_manifest_promises():
    """The matrix's releases and the one `make test` itself runs under (requirements-dev.txt's pin)."""
    with open(os.path.join(blender_matrix.ROOT, "requirements-dev.txt"), encoding="utf-8") as file:
        pinned = blender_matrix.PIN.search(file.read()).group(0).split("==")[1]
    releases = (*blender_matrix.BLENDER_RELEASES, pinned)
    series = {tuple(int(x) for x in release.split(".")[:2]) for release in releases}
    assert {(4, 2), (4, 5), (5, 0)} <= series
    assert pinned not in blender_matrix.BLENDER_RELEASES  # not run twice


def test_a_requirements_file_without_a_bpy_pin_is_refused(tmp_path, monkeypatch):
    (tmp_path / "requirements-dev.txt").write_text("numpy==1.26.4\n")
    monkeypatch.setattr(blender_matrix, "ROOT", str(tmp_path))
    with pytest.raises(SystemExit, match="pins no bpy"):
        blender_matrix.requirements_for("5.0.1")


def test_the_batch_smoke_runs_in_the_matrix_but_not_twice_in_make_test():
    """The matrix runs the batch smoke under each release; its name keeps `make test` (test_*.py) from collecting
    it, where tests/batch covers the pinned bpy."""
    for path in blender_matrix.SMOKE_TESTS:
        assert os.path.isfile(os.path.join(blender_matrix.ROOT, path))
        assert not os.path.basename(path).startswith("test_")
