"""Files and frame lists typed or written by someone else: whatever they hold, a reader returns data or raises
SkinkitError naming the file and line, never a raw ValueError, OverflowError or UnicodeDecodeError."""
import os
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skinkit import SkinkitError
from skinkit.framelist import MAX_FRAMES, parse_frame_list
from skinkit.meshcache import read_pc2, write_pc2
from skinkit.meshio import read_obj, read_obj_texture_corners

TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


def written(tmp_path, content, name="mesh.obj"):
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return str(path)


@pytest.mark.parametrize("content, message", [
    (TRIANGLE + "f a b c\n", r"mesh.obj:4: a vertex index 'a' is not a number"),
    (TRIANGLE + "f 1 2 100000000000000000000\n", r"mesh.obj:4: vertex index 100000000000000000000 refers to no vertex"),
    (TRIANGLE + "f 1 2 1e20\n", r"mesh.obj:4: a vertex index '1e20' is not a number"),
    (TRIANGLE + "f 1 2 0\n", r"mesh.obj:4: vertex index 0 refers to no vertex"),
    (TRIANGLE + "f 1 2 -4\n", r"mesh.obj:4: vertex index -4 refers to no vertex"),
    (TRIANGLE + "f 1 2 4\n", r"a face refers to vertex 4, but the file has 3"),
    (b"\xe2\x28\xa1 binary", r"mesh.obj: not a text OBJ file"),
])
def test_a_malformed_obj_is_refused_naming_the_line(tmp_path, content, message):
    with pytest.raises(SkinkitError, match=message):
        read_obj(written(tmp_path, content))


def test_negative_obj_indices_count_back_from_the_vertices_read_so_far(tmp_path):
    path = written(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nf 1 2 -1\n")
    _, triangles = read_obj(path)
    assert triangles.tolist() == [[0, 1, 2], [0, 1, 3]]


def test_texture_indices_of_a_malformed_obj_are_refused(tmp_path):
    with pytest.raises(SkinkitError, match=r"mesh.obj:4: a texture index 'x' is not a number"):
        read_obj_texture_corners(written(tmp_path, TRIANGLE + "f 1/x 2 3\n"))
    with pytest.raises(SkinkitError, match=r"texture index 99999999999999999999 refers to no texture"):
        read_obj_texture_corners(written(tmp_path, TRIANGLE + "vt 0 0\nf 1/99999999999999999999 2/1 3/1\n"))


@pytest.mark.parametrize("text, message", [
    ("5-1", r"the range 5-1 runs backwards \(write 1-5\)"),
    ("5--3", r"runs backwards"),
    (f"1-{MAX_FRAMES + 1}", rf"more than {MAX_FRAMES} frames"),
    ("1-3, a", r"expected numbers and ranges"),
    ("-", r"expected numbers and ranges"),
])
def test_a_frame_list_that_is_a_typing_mistake_is_refused(text, message):
    with pytest.raises(SkinkitError, match=message):
        parse_frame_list(text)


def test_frame_lists_take_negative_frames_and_ranges():
    assert parse_frame_list("-10--8, -1, 3-4") == [-10, -9, -8, -1, 3, 4]
    assert parse_frame_list("") == []


def test_a_pc2_that_is_missing_or_lies_about_its_size_is_refused(tmp_path):
    with pytest.raises(SkinkitError, match="No such file"):
        read_pc2(str(tmp_path / "missing.pc2"))
    path = str(tmp_path / "cache.pc2")
    write_pc2(path, np.zeros((2, 3, 3), np.float32))
    with open(path, "r+b") as stream:  # the header's point count at byte 16, made negative
        stream.seek(16)
        stream.write(struct.pack("<i", -3))
    with pytest.raises(SkinkitError, match="its header gives -3 points"):
        read_pc2(path)


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
OBJ_LINES = st.lists(st.one_of(
    st.builds(lambda *c: "v " + " ".join(c), *[st.sampled_from(["0", "1.5", "-2", "nan", "x", "1e999"])] * 3),
    st.builds(lambda *c: "f " + " ".join(c), *[st.sampled_from(["1", "2", "-1", "0", "3/1", "1//2", "a", "9" * 20,
                                                                "2/-1", "1/2/3", ""])] * 4),
    st.sampled_from(["vt 0 0", "vt 1", "# comment", "", "f", "v", "o name", "\x00"]),
    st.text(max_size=12)), max_size=12).map("\n".join)


@FUZZ
@given(content=st.one_of(OBJ_LINES, st.binary(max_size=64)))
def test_any_obj_content_gives_data_or_a_skinkit_error(tmp_path, content):
    path = written(tmp_path, content)
    for reader in (read_obj, read_obj_texture_corners):
        try:
            reader(path)
        except SkinkitError:
            pass


@FUZZ
@given(content=st.binary(max_size=64))
def test_any_pc2_content_gives_data_or_a_skinkit_error(tmp_path, content):
    path = written(tmp_path, b"POINTCACHE2\x00" + content, "cache.pc2")
    try:
        read_pc2(path)
    except SkinkitError:
        pass


@FUZZ
@given(text=st.text(alphabet="0123456789-, a", max_size=16))
def test_any_frame_list_gives_frames_or_a_skinkit_error(text):
    try:
        frames = parse_frame_list(text)
    except SkinkitError:
        return
    assert len(frames) <= MAX_FRAMES
