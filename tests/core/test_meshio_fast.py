"""The vectorised OBJ reader and writer: round trips, agreement with the line-by-line parser, threaded sequences
and malformed files refused naming the line."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skinkit import SkinkitError
from skinkit.meshio import (parse_obj_by_line, parse_obj_vectorised, read_obj, read_obj_sequence,
                            read_obj_texture_corners, write_obj)


def written(tmp_path, content, name="mesh.obj"):
    path = tmp_path / name
    path.write_text(content)
    return str(path)


def random_mesh(seed, vertex_count=50, triangle_count=80):
    generator = np.random.default_rng(seed)
    positions = generator.normal(size=(vertex_count, 3)) * 10.0 ** generator.integers(-3, 4)
    triangles = generator.integers(0, vertex_count, size=(triangle_count, 3)).astype(np.int32)
    return positions, triangles


@pytest.mark.parametrize("seed", range(4))
def test_written_meshes_read_back_the_same(tmp_path, seed):
    positions, triangles = random_mesh(seed)
    path = str(tmp_path / "mesh.obj")
    write_obj(path, positions, triangles)
    read_positions, read_triangles = read_obj(path)
    np.testing.assert_allclose(read_positions, positions, rtol=1e-8)  # written with 9 significant digits
    np.testing.assert_array_equal(read_triangles, triangles)
    assert read_triangles.dtype == np.int32


def test_texture_coordinates_read_back_through_the_corners(tmp_path):
    positions, triangles = random_mesh(7)
    corner_uv = np.random.default_rng(7).random((len(triangles), 3, 2))
    path = str(tmp_path / "mesh.obj")
    write_obj(path, positions, triangles, corner_uv)
    read_positions, read_triangles = read_obj(path)
    np.testing.assert_array_equal(read_triangles, triangles)
    texture = np.array([line.split()[1:] for line in open(path) if line.startswith("vt ")], dtype=np.float64)
    np.testing.assert_allclose(texture[read_obj_texture_corners(path)], corner_uv, rtol=1e-8)


def test_writing_matches_the_row_by_row_format(tmp_path):
    positions, triangles = random_mesh(3, 5, 4)
    path = str(tmp_path / "mesh.obj")
    write_obj(path, positions, triangles)
    expected = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in positions] + [f"f {a + 1} {b + 1} {c + 1}"
                                                                         for a, b, c in triangles]
    assert open(path).read().splitlines() == expected


IRREGULAR_FILES = [
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",                       # a quad: a fan of two
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 2 2\nf 1 2 3 4 5\nf 1 2 3\n",       # polygons of mixed size
    "v 0 0 0 1\nv 1 0 0\nv 1 1 0 0.5\nvt 0 0\nvn 0 0 1\nf 1/1/1 2//1 3/1\n",     # w, slashes
    "# made by hand\r\nv 0 0 0\r\nv 1 0 0\r\n\r\nv 1 1 0\r\nf 3 2 1\r\n",        # CRLF, blank lines
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3 -2 -1\n",                                 # indices counting back
    "v  0   0 0 \nv 1\t0 0\nv 1 1 0\nf  1  2  3 \n",                             # extra white space
    "v 0 0 0 # origin\nv 1 0 0\nv 1 1 0\nf 1 2 3\n",                         # a trailing comment
    "v 0 0 0\rv 1 0 0\rv 1 1 0\rf 1 2 3\r",                                   # old Mac line breaks
    "v 0 0 0\nv 1 0 0\x0cv 1 1 0\nf 1 2 3\n",                                 # a form feed breaks a line
]


@pytest.mark.parametrize("content", IRREGULAR_FILES)
def test_irregular_files_read_as_the_line_by_line_parser_reads_them(tmp_path, content):
    positions, triangles = read_obj(written(tmp_path, content))
    expected_positions, expected_triangles = parse_obj_by_line(content.splitlines(), "mesh.obj")
    np.testing.assert_array_equal(positions, expected_positions)
    np.testing.assert_array_equal(triangles, expected_triangles)


NUMBER = st.one_of(st.integers(-5, 5).map(str), st.floats(-1e6, 1e6, allow_nan=False).map(repr))
CORNER = st.integers(1, 6).map(str) | st.tuples(st.integers(1, 6), st.integers(1, 3)).map("{0[0]}/{0[1]}".format)
VALID_OBJ = st.lists(st.one_of(
    st.lists(NUMBER, min_size=3, max_size=4).map(lambda values: "v " + " ".join(values)),
    st.lists(CORNER, min_size=3, max_size=6).map(lambda corners: "f " + " ".join(corners)),
    st.sampled_from(["vt 0 0", "# comment", "", "o name"])), max_size=20).map(
    lambda lines: "\n".join([f"v {k} {k} {k}" for k in range(6)] + lines))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=VALID_OBJ)
def test_the_vectorised_parser_agrees_with_the_line_by_line_parser(content):
    try:
        positions, triangles = parse_obj_vectorised(content)
    except ValueError:
        return  # the reader then takes the line-by-line parser, which the other tests cover
    expected_positions, expected_triangles = parse_obj_by_line(content.splitlines(), "mesh.obj")
    np.testing.assert_array_equal(positions, expected_positions)
    np.testing.assert_array_equal(triangles, expected_triangles)


@pytest.mark.parametrize("content, message", [
    ("v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n", r"mesh.obj:2: a vertex coordinate is not a number"),
    ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", r"mesh.obj:2: a vertex needs three coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\n", r"mesh.obj:5: a face needs at least three corners"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3.5\n", r"mesh.obj:5: a vertex index '3.5' is not a number"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 nan\n", r"mesh.obj:4: a vertex index 'nan' is not a number"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3.0\n", r"mesh.obj:4: a vertex index '3.0' is not a number"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3e0\n", r"mesh.obj:4: a vertex index '3e0' is not a number"),
])
def test_a_malformed_file_is_refused_naming_the_line(tmp_path, content, message):
    with pytest.raises(SkinkitError, match=message):
        read_obj(written(tmp_path, content))


def test_a_sequence_keeps_the_files_order_and_refuses_a_file_with_other_vertices(tmp_path):
    positions, triangles = random_mesh(1)
    paths = []
    for frame in range(12):  # more files than reader threads
        paths.append(str(tmp_path / f"frame{frame}.obj"))
        write_obj(paths[-1], positions + frame, triangles)
    frames, read_triangles = read_obj_sequence(paths)
    np.testing.assert_allclose(frames, positions[None] + np.arange(12)[:, None, None], rtol=1e-8, atol=1e-6)
    np.testing.assert_array_equal(read_triangles, triangles)
    write_obj(paths[5], positions[:-1])
    with pytest.raises(SkinkitError, match=r"frame5.obj: 49 vertices, but .*frame0.obj has 50"):
        read_obj_sequence(paths)
    with pytest.raises(SkinkitError, match=r"path: expected"):
        read_obj_sequence([paths[0], 7])
    with open(paths[8], "w") as stream:
        stream.write("# a later frame\nv 0 0 0\nf 1 1 1\nv 0 0 x\n")
    with pytest.raises(SkinkitError, match=r"frame8.obj:4: a vertex coordinate is not a number"):
        read_obj_sequence(paths)
