"""`skinkit runtime-bench` as a user runs it: a small synthetic crowd, one JSON object with the frame times, the
speedup of culling + LOD over full detail and the pixel error; bad arguments refused as one JSON error."""
from tests.cli.test_cli import skinkit


def test_small_crowd_report():
    code, result = skinkit("runtime-bench", "--characters", "8", "--vertices", "2000:4000", "--kinds", "2",
                           "--frames", "2", "--repeats", "1", "--kernel", "scalar", "--threads", "1", "--json")
    assert code == 0
    assert result["characters"] == 8 and result["kernel"] == "scalar" and "scalar" in result["kernels_available"]
    assert len(result["frames"]) == 2
    for frame in result["frames"]:
        assert frame["full_ms"] > 0 and frame["lod_ms"] > 0
        assert frame["drawn_vertices"] <= frame["full_vertices"]
        assert 0 <= frame["visible"] <= 8
        assert frame["pixel_error"] <= 1.0 + 1e-3  # the default tolerance, which the measured epsilons honour
    assert result["triad_gb_per_s"] > 0 and result["full_detail_mverts_per_s"] > 0


def test_bad_arguments_are_one_json_error():
    code, result = skinkit("runtime-bench", "--vertices", "9:3", "--json", expect_success=False)
    assert code == 1 and "--vertices" in result["error"]
    code, result = skinkit("runtime-bench", "--characters", "0", "--json", expect_success=False)
    assert code == 1 and "--characters" in result["error"]
