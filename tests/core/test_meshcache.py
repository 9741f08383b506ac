import numpy as np
import pytest

from skinkit import SkinkitError, meshcache


def test_pc2_round_trip(tmp_path):
    positions = np.random.default_rng(0).normal(size=(7, 13, 3)).astype(np.float32)
    path = str(tmp_path / "cache.pc2")
    meshcache.write_pc2(path, positions, start_frame=5, sample_rate=1.0)
    read, start, rate = meshcache.read_pc2(path)
    assert np.array_equal(read, positions) and start == 5 and rate == 1.0
    with open(path, "rb") as stream:
        assert stream.read(12) == b"POINTCACHE2\0"


def test_pc2_refuses_bad_input(tmp_path):
    with pytest.raises(SkinkitError, match="expected shape"):
        meshcache.write_pc2(str(tmp_path / "x.pc2"), np.zeros((0, 3, 3)))
    truncated = tmp_path / "t.pc2"
    meshcache.write_pc2(str(truncated), np.zeros((2, 4, 3)))
    truncated.write_bytes(truncated.read_bytes()[:-4])
    with pytest.raises(SkinkitError, match="truncated"):
        meshcache.read_pc2(str(truncated))
    (tmp_path / "n.pc2").write_bytes(b"nonsense")
    with pytest.raises(SkinkitError, match="not a PC2"):
        meshcache.read_pc2(str(tmp_path / "n.pc2"))
