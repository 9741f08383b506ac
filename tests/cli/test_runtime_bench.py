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


def test_fixed_layout_draws_the_same_frames():
    """--layout fixed skins the crowd pack's FixedPack: the same cameras cull, choose and draw the same vertices,
    with the same pixel error as the CSR pack (float rounding apart), and says its slots per vertex."""
    arguments = ("runtime-bench", "--characters", "6", "--vertices", "1500:3000", "--kinds", "2", "--frames", "2",
                 "--repeats", "1", "--threads", "1", "--influences", "3", "--json")
    _, csr = skinkit(*arguments)
    code, fixed = skinkit(*arguments, "--layout", "fixed")
    assert code == 0 and csr["layout"] == "csr" and fixed["layout"] == "fixed"
    assert fixed["slots_per_vertex"] % 2 == 0 and fixed["slots_per_vertex"] >= 4  # 3 influences padded to even
    assert fixed["floats_per_slot"] == 8  # the crowd geomorphs
    for a, b in zip(csr["frames"], fixed["frames"]):
        assert (a["visible"], a["drawn_vertices"], a["full_vertices"]) == (b["visible"], b["drawn_vertices"],
                                                                           b["full_vertices"])
        assert abs(a["pixel_error"] - b["pixel_error"]) <= 1e-3
    assert fixed["full_detail_gb_per_s"] > 0
