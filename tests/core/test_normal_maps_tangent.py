"""Tangent maps through numpy: a bent two-bone plane's tangent map gives, in random poses, the posed source face
normal at every texel (the exact per-texel evaluation); tiles share their largest count; the multi-channel EXR reads
back what was written; bad input is refused."""
import numpy as np
import pytest

import skinkit
from skinkit import SkinkitError
from skinkit import normal_maps as nm
from tests.core.test_normal_maps import grid


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.fixture(scope="module")
def bent_plane():
    triangles, positions, uv = grid(12, lambda x, y: 0.1 * np.sin(3 * x) * np.cos(2 * y))
    rest_frames = np.stack([np.eye(4), np.eye(4)])
    rest_frames[1, :3, 3] = (0.5, 0.0, 0.0)
    skeleton = skinkit.Skeleton.create(np.array([-1, 0]), rest_frames)
    child = np.clip((positions[:, 0] - 0.3) / 0.4, 0.0, 1.0)  # blends across the middle
    weights = skinkit.SparseWeights.from_dense(np.stack([1 - child, child], axis=1))
    model = skinkit.convert_lbs(skeleton, weights, positions)
    source = nm.BakeSurface.from_arrays(triangles, positions, uv)
    target = nm.BakeSurface.from_arrays(*grid(3))
    return target, source, model


def test_posed_normals_are_the_posed_source_faces(bent_plane):
    target, source, model = bent_plane
    tangent_map = nm.bake_tangent_map(target, source, model, size=48, tile=8, max_influences=4)
    filled = tangent_map.coverage == nm.COVERAGE["filled"]
    assert filled.all() and tangent_map.counts.max() == 2 and tangent_map.counts.min() == 1
    rng = np.random.default_rng(3)
    for _ in range(4):
        poses = np.stack([np.eye(4), np.eye(4)])
        poses[1, :3, :3] = rotation(rng.normal(size=3), rng.uniform(0.2, 1.2))
        poses[1, :3, 3] = (0.5, 0.0, 0.0) + rng.normal(scale=0.1, size=3)
        decoded = 2.0 * tangent_map.normal_map(poses).astype(np.float64) - 1.0
        posed = model.evaluate(poses)[source.triangles]  # (T, 3, 3)
        faces = np.cross(posed[:, 1] - posed[:, 0], posed[:, 2] - posed[:, 0])
        faces /= np.linalg.norm(faces, axis=1, keepdims=True)
        exact = faces[tangent_map.source_triangles[filled]]
        got = decoded[filled] / np.linalg.norm(decoded[filled], axis=1, keepdims=True)
        degrees = np.degrees(np.arccos(np.clip((got * exact).sum(1), -1, 1)))
        assert degrees.max() < 0.05  # float32 storage of the encoded normal
    rest_pose = np.stack([np.eye(4), np.eye(4)])
    rest_pose[1, :3, 3] = (0.5, 0.0, 0.0)
    rest = 2.0 * tangent_map.normal_map(rest_pose).astype(np.float64) - 1.0
    assert rest[filled][:, 2].min() > 0.5  # in the rest pose the bumpy plane faces +z


def test_tiles_share_the_largest_count(bent_plane):
    target, source, model = bent_plane
    tangent_map = nm.bake_tangent_map(target, source, model, size=40, tile=8, max_influences=4)
    tiles = tangent_map.tile_counts()
    assert tiles.shape == (5, 5)
    padded = tangent_map.padded_counts()
    assert (padded >= tangent_map.counts).all()
    for ty in range(5):
        for tx in range(5):
            block = tangent_map.counts[8 * ty:8 * ty + 8, 8 * tx:8 * tx + 8]
            assert tiles[ty, tx] == block.max()
    slots = tangent_map.tangents.shape[2]
    unused = np.arange(slots)[None, None, :] >= tangent_map.counts[..., None]
    assert (tangent_map.tangents[unused] == 0).all() and (tangent_map.bones[unused] == 0).all()


def test_the_exr_reads_back(bent_plane, tmp_path):
    import OpenImageIO as oiio

    target, source, model = bent_plane
    tangent_map = nm.bake_tangent_map(target, source, model, size=16, tile=4, max_influences=4)
    path = nm.write_tangent_map(str(tmp_path / "tangents.exr"), tangent_map)
    image_input = oiio.ImageInput.open(path)
    spec = image_input.spec()
    pixels = image_input.read_image(oiio.FLOAT)
    image_input.close()
    names = list(spec.channelnames)  # OpenEXR stores channels sorted by name
    assert spec.nchannels == 2 * 9 and {"bone0", "bone1", "t1_0.X", "t2_1.W"} <= set(names)
    assert spec.getattribute("skinkit:tile") == 4
    for slot in (0, 1):
        np.testing.assert_array_equal(pixels[..., names.index(f"bone{slot}")],
                                      tangent_map.bones[..., slot].astype(np.float32))
        for which, label in ((0, "t1"), (1, "t2")):
            for d, axis in enumerate("XYZW"):
                np.testing.assert_array_equal(pixels[..., names.index(f"{label}_{slot}.{axis}")],
                                              tangent_map.tangents[:, :, slot, which, d].astype(np.float32))
    counts = [int(c) for c in spec.getattribute("skinkit:tile_counts").split()]
    assert counts == tangent_map.tile_counts().reshape(-1).tolist()


def test_bad_input(bent_plane):
    target, source, model = bent_plane
    with pytest.raises(SkinkitError, match="more than max_influences = 1"):
        nm.bake_tangent_map(target, source, model, size=16, max_influences=1)
    with pytest.raises(SkinkitError, match="model: has"):
        nm.bake_tangent_map(target, target, model, size=16)
    tangent_map = nm.bake_tangent_map(target, source, model, size=16, max_influences=2)
    with pytest.raises(SkinkitError, match="bone 1 is outside 0-0"):
        tangent_map.normal_map(np.eye(4)[None])


def test_the_mip_chain_averages_blocks_by_the_bivector_fit(bent_plane):
    target, source, model = bent_plane
    fine = nm.bake_tangent_map(target, source, model, size=32, tile=8, max_influences=4)
    chain = fine.mip_chain()
    assert [m.counts.shape[0] for m in chain] == [32, 16, 8, 4, 2, 1]
    coarse = chain[1]
    for row in range(16):
        for column in range(16):
            block = fine.bones[2 * row:2 * row + 2, 2 * column:2 * column + 2]
            block_counts = fine.counts[2 * row:2 * row + 2, 2 * column:2 * column + 2]
            union = {int(b) for (y, x), count in np.ndenumerate(block_counts) for b in block[y, x, :count]}
            assert set(coarse.bones[row, column, :coarse.counts[row, column]].tolist()) == union  # sparse
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, :3, :3] = rotation((0.3, 1.0, 0.2), 0.9)
    poses[1, :3, 3] = (0.5, 0.05, 0.1)
    fine_normals = 2.0 * fine.normal_map(poses).astype(np.float64) - 1.0
    blocks = fine_normals.reshape(16, 2, 16, 2, 3).sum(axis=(1, 3))
    blocks /= np.linalg.norm(blocks, axis=-1, keepdims=True)
    coarse_normals = 2.0 * coarse.normal_map(poses).astype(np.float64) - 1.0
    coarse_normals /= np.linalg.norm(coarse_normals, axis=-1, keepdims=True)
    degrees = np.degrees(np.arccos(np.clip((blocks * coarse_normals).sum(-1), -1, 1)))
    # Near the blocks' average posed normal (not equal: the fit is in animation space, and a block straddling a
    # crease of the faceted source averages tangents of different lengths).
    assert np.median(degrees) < 0.05 and degrees.mean() < 1.0 and degrees.max() < 10.0
    # The C fit equals a direct numpy one: A = sum a b^T - b a^T, its top singular pair, the mean pair projected.
    for row, column in ((0, 0), (5, 7), (8, 3), (15, 15)):
        pairs, union = [], sorted(set(coarse.bones[row, column, :coarse.counts[row, column]].tolist()))
        for y in (2 * row, 2 * row + 1):
            for x in (2 * column, 2 * column + 1):
                vector = np.zeros((2, 4 * len(union)))
                for k in range(fine.counts[y, x]):
                    slot = union.index(int(fine.bones[y, x, k]))
                    vector[:, 4 * slot:4 * slot + 4] += fine.tangents[y, x, k]
                pairs.append(vector)
        pairs = np.array(pairs)
        matrix = sum(np.outer(a, b) - np.outer(b, a) for a, b in pairs)
        u, _, vt = np.linalg.svd(matrix)
        plane = np.stack([u[:, 0], vt[0]])
        expected = pairs.mean(axis=0) @ plane.T @ plane
        got = coarse.tangents[row, column, :len(union)].transpose(1, 0, 2).reshape(2, -1)
        np.testing.assert_allclose(got, expected, atol=1e-10)
    # A block whose four texels carry one pair keeps it exactly.
    single = nm.TangentMap(np.ones((2, 2), np.int32), np.zeros((2, 2, 1), np.int32),
                           np.broadcast_to(np.array([[1.0, 0, 0, 0], [0, 2.0, 0, 0]]), (2, 2, 1, 2, 4)).copy(),
                           np.zeros((2, 2), np.int32), np.ones((2, 2), np.uint8), 8)
    np.testing.assert_allclose(single.downsample().tangents[0, 0, 0], [[1, 0, 0, 0], [0, 2, 0, 0]], atol=1e-12)
    with pytest.raises(SkinkitError, match="cannot be halved"):
        chain[-1].downsample()


def random_pose_statistics(rng, count=40):
    """Statistics of random poses of the two-bone plane: bone 1 rotates about its joint at x = 0.5."""
    from skinkit.metrics import PoseStatistics

    world = np.tile(np.eye(4), (count, 2, 1, 1))
    for pose in world:
        pose[1, :3, :3] = rotation(rng.normal(size=3), rng.uniform(0.1, 1.4))
        pose[1, :3, 3] = (0.5, 0.0, 0.0)
    return PoseStatistics.from_world_samples(np.array([-1, 0]), world), world


def test_the_mip_fit_in_the_metric_matches_a_dense_reference(bent_plane):
    """Appendix A.1.2: with C = P^(1/2) over the whole skeleton (dense), the top singular pair (u, v) of C A C^T,
    a = A C^T v / s, b = -A C^T u / s, and the mean pair projected P-orthogonally onto span(a, b); the core forms
    only P's sub-block on each block's bones."""
    target, source, model = bent_plane
    rng = np.random.default_rng(7)
    statistics, _ = random_pose_statistics(rng)
    fine = nm.bake_tangent_map(target, source, model, size=32, tile=8, max_influences=4)
    coarse = fine.downsample(statistics)
    euclidean = fine.downsample()
    p = statistics.matrix()
    values, vectors = np.linalg.eigh(p)
    root = vectors @ np.diag(np.sqrt(np.clip(values, 0, None))) @ vectors.T
    moved = 0.0
    for row in range(16):
        for column in range(16):
            pairs = []
            for y in (2 * row, 2 * row + 1):
                for x in (2 * column, 2 * column + 1):
                    vector = np.zeros((2, 8))  # both bones, dense
                    for k in range(fine.counts[y, x]):
                        bone = int(fine.bones[y, x, k])
                        vector[:, 4 * bone:4 * bone + 4] += fine.tangents[y, x, k]
                    pairs.append(vector)
            pairs = np.array(pairs)
            matrix = sum(np.outer(a, b) - np.outer(b, a) for a, b in pairs)
            u, sigma, vt = np.linalg.svd(root @ matrix @ root.T)
            a, b = matrix @ root.T @ vt[0] / sigma[0], -matrix @ root.T @ u[:, 0] / sigma[0]
            expected = np.stack([a * (a @ p @ x) + b * (b @ p @ x) for x in pairs.mean(axis=0)])
            got = np.zeros((2, 8))
            for k in range(coarse.counts[row, column]):
                bone = int(coarse.bones[row, column, k])
                got[:, 4 * bone:4 * bone + 4] = coarse.tangents[row, column, k].reshape(2, 4)
            np.testing.assert_allclose(got, expected, atol=1e-9 * np.abs(expected).max())
            moved = max(moved, float(np.abs(coarse.tangents[row, column] - euclidean.tangents[row, column]).max()))
    assert moved > 1e-4  # the metric fit is not the Euclidean one on this data
    # Sparse as the Euclidean fit: the same bones per texel; the chain takes the statistics too.
    np.testing.assert_array_equal(coarse.counts, euclidean.counts)
    np.testing.assert_array_equal(coarse.bones, euclidean.bones)
    np.testing.assert_allclose(fine.mip_chain(2, statistics)[1].tangents, coarse.tangents, atol=0)
    with pytest.raises(SkinkitError, match="statistics: expected a PoseStatistics"):
        fine.downsample(np.eye(8))


def test_a_tangent_map_bake_cancels_midway_and_reports_its_rows(bent_plane):
    target, source, model = bent_plane
    fractions = []
    with pytest.raises(SkinkitError, match="cancelled at row 64 of 96"):
        nm.bake_tangent_map(target, source, model, size=96, max_influences=4,
                            progress=lambda fraction: fractions.append(fraction) or len(fractions) == 2)
    assert fractions == [pytest.approx(1 / 3), pytest.approx(2 / 3)]
    fractions.clear()
    whole = nm.bake_tangent_map(target, source, model, size=96, max_influences=4, progress=fractions.append)
    assert fractions == [pytest.approx(1 / 3), pytest.approx(2 / 3), 1.0]
    assert np.array_equal(whole.counts, nm.bake_tangent_map(target, source, model, size=96, max_influences=4).counts)
