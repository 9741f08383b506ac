"""skinkit.normal_maps through numpy: an analytic bump baked from a high-resolution copy of a plane (atlas, ray
cast and guided), the guided bake's choice between the other two, a surface baked onto itself is flat, the written
images read back bit-exact through OpenImageIO, and bad input is refused with the parameter named."""
import numpy as np
import pytest

from skinkit import SkinkitError
from skinkit import normal_maps as nm

BUMP = 0.03


def grid(n, height=lambda x, y: 0 * x):
    xs = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs)
    positions = np.stack([x, y, height(x, y)], -1).reshape(-1, 3)
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]
    triangles = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return triangles, positions, positions[:, :2][triangles]


def bump(x, y):
    return BUMP * np.sin(2 * np.pi * x) * np.sin(2 * np.pi * y)


def bump_normal(x, y):
    hx = BUMP * 2 * np.pi * np.cos(2 * np.pi * x) * np.sin(2 * np.pi * y)
    hy = BUMP * 2 * np.pi * np.sin(2 * np.pi * x) * np.cos(2 * np.pi * y)
    normal = np.stack([-hx, -hy, np.ones_like(hx)], -1)
    return normal / np.linalg.norm(normal, axis=-1, keepdims=True)


def texel_centres(size):
    centres = (np.arange(size) + 0.5) / size
    return np.meshgrid(centres, 1.0 - centres)  # row 0 is the top (v = 1)


@pytest.fixture(scope="module")
def plane_and_bump():
    target = nm.BakeSurface.from_arrays(*grid(4))
    triangles, positions, uv = grid(96, bump)
    # The smooth normals of the fine mesh (no analytic help): the bake must recover the bump from geometry.
    source = nm.BakeSurface.from_arrays(triangles, positions, uv)
    return target, source


@pytest.mark.parametrize("mode", ["atlas", "ray", "guided"])
def test_the_analytic_bump_is_baked(plane_and_bump, mode):
    target, source = plane_and_bump
    result = nm.bake_normals(target, source, size=64, mode=mode, cage=0.1, margin=2)
    u, v = texel_centres(64)
    decoded = 2.0 * result.image.astype(np.float64) - 1.0
    decoded /= np.linalg.norm(decoded, axis=-1, keepdims=True)
    degrees = np.degrees(np.arccos(np.clip((decoded * bump_normal(u, v)).sum(-1), -1, 1)))
    assert result.filled == 64 * 64 and result.missed == 0
    assert degrees.mean() < 0.3 and degrees.max() < 1.0
    # The exact normals at the centres are the source's own: the bake is within its supersampling of them.
    mean, largest = result.angular_error()
    assert mean < 0.05 and largest < 0.2
    # A flat map decoded in the same frames is as far off as the bump itself.
    flat = np.broadcast_to(np.float32([0.5, 0.5, 1.0]), result.image.shape)
    assert result.angular_error(flat)[0] > 5.0


@pytest.mark.parametrize("mode", ["atlas", "ray", "guided"])
def test_a_bake_without_diagnostics_gives_the_same_image_on_any_thread_count(plane_and_bump, mode):
    target, source = plane_and_bump
    full = nm.bake_normals(target, source, size=72, mode=mode, cage=0.1, supersample=1, margin=3, thread_count=1)
    for threads in (1, 2, 3):
        lean = nm.bake_normals(target, source, size=72, mode=mode, cage=0.1, supersample=1, margin=3,
                               thread_count=threads, diagnostics=False)
        assert lean.exact is None and lean.frames is None
        assert np.array_equal(lean.image, full.image) and np.array_equal(lean.coverage, full.coverage)
    with pytest.raises(SkinkitError, match="diagnostics=True"):
        lean.angular_error()
    # One sample per texel is the texel centre: the bump there within float storage.
    u, v = texel_centres(72)
    decoded = 2.0 * full.image.astype(np.float64) - 1.0
    decoded /= np.linalg.norm(decoded, axis=-1, keepdims=True)
    assert np.degrees(np.arccos(np.clip((decoded * bump_normal(u, v)).sum(-1), -1, 1))).mean() < 0.3


def decoded(image):
    normals = 2.0 * image.astype(np.float64) - 1.0
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def test_the_guided_bake_takes_the_ray_where_it_agrees_with_the_atlas_else_the_atlas():
    """The target plane takes the left half of the atlas, as the bumpy source's own surface does, but shifted and
    shrunk by 1%, so that the same uv point lies beside the point above (a level's uvs after its vertices moved):
    the ray's normal is the bump's at the point above, the atlas' a degree or so from it. A second source
    sheet, tilted 27 degrees and with uvs of its own in the right half, crosses the bump's peak, so that for a band
    of texels the ray along the plane's normal meets the sheet before the bump. There the ray's normal is the
    sheet's, far from the same uv point's, and the guided bake keeps the atlas'; everywhere else it is the ray's."""
    triangles, positions, uv = grid(96, bump)
    uv = uv * [0.5, 1.0]
    sheet_triangles, sheet_positions, sheet_uv = grid(8)
    sheet_positions = sheet_positions * [0.2, 0.2, 0.0] + [0.15, 0.15, 0.0]
    sheet_positions[:, 2] = 0.01 + 0.5 * (sheet_positions[:, 0] - 0.25)
    source = nm.BakeSurface.from_arrays(np.concatenate([triangles, sheet_triangles + len(positions)]),
                                        np.concatenate([positions, sheet_positions]),
                                        np.concatenate([uv, 0.55 + 0.4 * sheet_uv]))
    plane_triangles, plane_positions, plane_uv = grid(4)
    target = nm.BakeSurface.from_arrays(plane_triangles, plane_positions, (0.98 * plane_uv + 0.01) * [0.5, 1.0])
    maps = {mode: nm.bake_normals(target, source, size=128, mode=mode, cage=0.1, supersample=1, margin=0)
            for mode in ("atlas", "ray", "guided")}
    filled = maps["guided"].coverage == nm.COVERAGE["filled"]
    atlas, ray, guided = (decoded(maps[mode].image) for mode in ("atlas", "ray", "guided"))
    apart = np.degrees(np.arccos(np.clip((atlas * ray).sum(-1), -1, 1)))
    agree, disagree = filled & (apart < nm.GUIDE_DEGREES - 0.5), filled & (apart > nm.GUIDE_DEGREES + 0.5)
    assert disagree.sum() > 100 and agree.sum() > 4000  # the sheet's band, and the bump elsewhere
    assert np.percentile(apart[agree], 90) > 0.3  # the ray and the atlas tell apart where they agree, too
    np.testing.assert_allclose(guided[agree], ray[agree], atol=1e-5)
    np.testing.assert_allclose(guided[disagree], atlas[disagree], atol=1e-5)
    # The band is the sheet's: 45 degrees off the bump's normal with the ray, the bump's own with the guided map.
    u, v = texel_centres(128)
    exact = bump_normal(2 * u, v)
    error = {name: np.degrees(np.arccos(np.clip((normals * exact).sum(-1), -1, 1)))[disagree]
             for name, normals in (("ray", ray), ("guided", guided))}
    assert error["ray"].min() > 15 and error["guided"].max() < 1.0


def test_a_surface_baked_onto_itself_is_flat():
    triangles, positions, uv = grid(6, lambda x, y: 0.2 * np.sin(3 * x) * np.cos(2 * y))
    surface = nm.BakeSurface.from_arrays(triangles, positions, uv)
    for mode in ("atlas", "ray", "guided"):
        result = nm.bake_normals(surface, surface, size=48, mode=mode, margin=4)
        filled = result.coverage == nm.COVERAGE["filled"]
        assert filled.all()
        assert np.abs(result.image[filled] - np.float32([0.5, 0.5, 1.0])).max() <= 1.0 / 255


@pytest.mark.parametrize("format", list(nm.FORMATS))
def test_images_read_back_bit_exact(tmp_path, format):
    rng = np.random.default_rng(7)
    image = rng.random((33, 47, 3)).astype(np.float32)
    path = nm.write_image(str(tmp_path / f"map{nm.FORMATS[format][1]}"), image, format)
    stored = nm.quantize(image, format)
    back = nm.read_image(path)
    assert back.dtype == stored.dtype and back.shape == stored.shape
    np.testing.assert_array_equal(back, stored)
    assert list(tmp_path.iterdir()) == [tmp_path / f"map{nm.FORMATS[format][1]}"]  # no partial file left


def test_bad_input_is_named(tmp_path):
    target = nm.BakeSurface.from_arrays(*grid(2))
    with pytest.raises(SkinkitError, match="target: no uv"):
        nm.bake_normals(nm.BakeSurface(target.triangles, target.positions, target.normals, None), target)
    with pytest.raises(SkinkitError, match="mode"):
        nm.bake_normals(target, target, mode="sideways")
    with pytest.raises(SkinkitError, match="outside 0-1"):
        triangles, positions, uv = grid(2)
        nm.bake_normals(nm.BakeSurface.from_arrays(triangles, positions, uv * 1.5), target, size=8)
    triangles, positions, uv = grid(2)
    uv[1] = uv[0]
    with pytest.raises(SkinkitError, match=r"\d+ texels are covered by more than one target triangle"):
        nm.bake_normals(nm.BakeSurface.from_arrays(triangles, positions, uv), target, size=16)
    with pytest.raises(SkinkitError, match="surface triangles"):
        nm.BakeSurface.from_arrays([[0, 1, 9]], np.zeros((3, 3)))
    with pytest.raises(SkinkitError, match="not writable|does not exist"):
        nm.write_image(str(tmp_path / "missing" / "map.png"), np.zeros((4, 4, 3)), "png8")
    with pytest.raises(SkinkitError, match="format"):
        nm.quantize(np.zeros((2, 2, 3)), "jpeg")


def test_progress_cancels():
    target = nm.BakeSurface.from_arrays(*grid(2))
    seen = []
    with pytest.raises(SkinkitError, match="cancelled"):
        nm.bake_normals(target, target, size=128, progress=lambda fraction: seen.append(fraction) or True)
    assert len(seen) == 1 and 0 < seen[0] < 1



def blade(segments, half_width, offset=0.0):
    """A thin blade (a hoof's or an ear's edge): two faces from a ridge at z = 1 down to feet at y = -+half_width,
    z = 0, each moved `offset` along its own outward normal (offset 0: one ridge vertex per x, shared by both faces).
    Triangles, positions, uv (face -y left, face +y right in the atlas) and each triangle's face normal."""
    xs = np.linspace(0.0, 1.0, segments + 1)
    ridge = [np.array([x, 0.0, 1.0]) for x in xs]
    positions, triangles, uv, normals = [] if offset else list(ridge), [], [], []
    for side, u0 in ((-1.0, 0.0), (1.0, 0.55)):
        normal = np.array([0.0, side, half_width]) / np.hypot(1.0, half_width)
        tops = list(range(len(positions), len(positions) + len(xs))) if offset else list(range(len(xs)))
        if offset:
            positions += [p + offset * normal for p in ridge]
        feet = list(range(len(positions), len(positions) + len(xs)))
        positions += [np.array([x, side * half_width, 0.0]) + offset * normal for x in xs]
        for i in range(segments):
            quad = [(tops[i], feet[i], feet[i + 1]), (tops[i], feet[i + 1], tops[i + 1])]
            for corners in quad if side > 0 else [q[::-1] for q in quad]:
                triangles.append(corners)
                normals.append(normal)
                uv.append([(u0 + 0.45 * xs[i + (c in (feet[i + 1], tops[i + 1]))], 1.0 if c in tops else 0.0)
                           for c in corners])
    return np.array(triangles, np.int32), np.array(positions), np.array(uv), np.array(normals)


def test_grazing_normals_of_a_thin_blade_are_baked():
    """The cause of the horse's unbaked texels: where a coarse level folds sharply (a blade 0.1 wide and 1 high),
    the smooth normals at the ridge lie almost in both faces, so the rays along them run beside a source 0.005 off
    the faces and leave the cage; every texel is baked all the same, with the normal of the face it lies on."""
    triangles, positions, uv, faces = blade(4, 0.05)
    target = nm.BakeSurface.from_arrays(triangles, positions, uv)
    ridge_tilt = np.einsum("tcj,tj->tc", target.normals, faces)[:, 0]
    assert np.degrees(np.arccos(ridge_tilt)).min() > 85.0  # the cause: normals grazing the faces at the ridge
    source_triangles, source_positions, _, source_faces = blade(4, 0.05, offset=0.005)
    source = nm.BakeSurface.from_arrays(source_triangles, source_positions, normals=np.repeat(source_faces, 3, 0)
                                        .reshape(-1, 3, 3))
    result = nm.bake_normals(target, source, size=64, mode="ray", cage=0.02, margin=0, supersample=1)
    covered = result.coverage != nm.COVERAGE["empty"]
    assert result.missed == 0 and result.filled == covered.sum() > 1000
    # Every exact normal is one of the two faces' normals.
    exact = result.exact[covered]
    assert np.minimum(np.abs(exact - source_faces[0]).max(1), np.abs(exact - source_faces[-1]).max(1)).max() < 1e-9


def decoded_in_interpolated_frames(image, target, tangents, unnormalised):
    """Each texel's map value decoded as the Normal Map node does, normalize(x T + y B + z N) with T, N the target's
    tangent and normal interpolated at the texel centre (left unnormalised, as Cycles and MikkTSpace decode, or
    normalised first) and B = sign N x T, computed here from the corners, independently of the bake's frames."""
    size = image.shape[0]
    u, v = texel_centres(size)
    points = np.stack([u, v], -1).reshape(-1, 2)
    decoded = np.zeros((len(points), 3))
    encoded = 2.0 * image.reshape(-1, 3).astype(np.float64) - 1.0
    for t, corners in enumerate(target.uv):
        matrix = np.column_stack([corners[1] - corners[0], corners[2] - corners[0]])
        w12 = np.linalg.solve(matrix, (points - corners[0]).T).T
        weights = np.column_stack([1 - w12.sum(1), w12])
        inside = (weights >= -1e-12).all(1)
        tangent = weights[inside] @ tangents[t, :, :3]
        normal = weights[inside] @ target.normals[t]
        sign = np.where(weights[inside] @ tangents[t, :, 3] < 0, -1.0, 1.0)
        if not unnormalised:
            tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        bitangent = sign[:, None] * np.cross(normal, tangent)
        x = encoded[inside]
        decoded[inside] = x[:, :1] * tangent + x[:, 1:2] * bitangent + x[:, 2:] * normal
    decoded /= np.maximum(np.linalg.norm(decoded, axis=1, keepdims=True), 1e-300)
    return decoded.reshape(size, size, 3)


def test_the_bake_inverts_the_normal_map_nodes_decoding_in_unnormalised_frames():
    """Corner normals spread 35 degrees apart (a coarse level's smooth normals) make the interpolated normal and
    tangent shorter than 1 inside a triangle. Cycles' Normal Map node decodes with those vectors as they are, so the
    bake must encode in the same frame: decoded that way the map gives the source normal exactly."""
    triangles, positions, uv = grid(1)
    tilted = np.array([[-0.3, -0.3, 1.0], [0.3, -0.3, 1.0], [0.3, 0.3, 1.0], [-0.3, 0.3, 1.0]])
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    target = nm.BakeSurface.from_arrays(triangles, positions, uv, normals=tilted[triangles])
    fine_triangles, fine_positions, fine_uv = grid(32, bump)
    source = nm.BakeSurface.from_arrays(fine_triangles, fine_positions, fine_uv)
    tangents = nm.mikktspace_tangents(target)
    for supersample in (1, 3):
        result = nm.bake_normals(target, source, size=32, mode="atlas", supersample=supersample, margin=0,
                                 tangents=tangents)
        mask = result.coverage == nm.COVERAGE["filled"]
        assert mask.all()
        as_the_node_decodes = decoded_in_interpolated_frames(result.image, target, tangents, unnormalised=True)
        degrees = np.degrees(np.arccos(np.clip((as_the_node_decodes * result.exact).sum(-1), -1, 1)))[mask]
        if supersample == 1:  # the sample is the texel centre, where exact is measured
            assert degrees.max() < 0.01
        else:
            assert degrees.mean() < 0.3
        # Decoding in normalised frames instead is measurably off: the test can tell the two conventions apart.
        normalised = decoded_in_interpolated_frames(result.image, target, tangents, unnormalised=False)
        off = np.degrees(np.arccos(np.clip((normalised * result.exact).sum(-1), -1, 1)))[mask]
        assert off.max() > 0.1


def opposite_squares(squares, size, seed):
    """A plane of uv squares a texel apart (one empty texel between neighbours), each baked from a source whose
    normals are +z or -z: a gap texel between opposite squares has neighbours that cancel."""
    rng = np.random.default_rng(seed)
    cell, texel = 1.0 / squares, 1.0 / size
    triangles, positions, normals, uv = [], [], [], []
    for j in range(squares):
        for i in range(squares):
            u0, v0, u1, v1 = i * cell + 0.1 * texel, j * cell + 0.1 * texel, (i + 1) * cell - 1.1 * texel, \
                (j + 1) * cell - 1.1 * texel
            corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
            base, sign = len(positions), rng.choice([-1.0, 1.0])
            positions += [(u, v, 0.0) for u, v in corners]
            for a, b, c in ((0, 1, 2), (0, 2, 3)):
                triangles.append((base + a, base + b, base + c))
                uv.append([corners[a], corners[b], corners[c]])
                normals.append([(0.0, 0.0, sign)] * 3)
    triangles, positions, uv = np.array(triangles, np.int32), np.array(positions), np.array(uv)
    target = nm.BakeSurface(triangles, positions, np.tile([0.0, 0.0, 1.0], (len(triangles), 3, 1)), uv)
    return target, nm.BakeSurface(triangles, positions, np.array(normals), uv)


def dilated_reference(image, coverage, margin):
    """The margin's rule, pass by pass: an empty texel with 8-neighbours baked before the pass takes the normalised
    sum of their decoded normals (summed in row-major order, in doubles), unless that sum is zero."""
    image, baked = image.astype(np.float64), coverage != nm.COVERAGE["empty"]
    size = len(image)
    for _ in range(margin):
        padded = np.pad(2.0 * image - 1.0, ((1, 1), (1, 1), (0, 0)))
        known = np.pad(baked, 1)
        total, count = np.zeros_like(image), np.zeros((size, size), int)
        for dy, dx in [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]:
            here = known[1 + dy:1 + dy + size, 1 + dx:1 + dx + size]
            total += np.where(here[..., None], padded[1 + dy:1 + dy + size, 1 + dx:1 + dx + size], 0.0)
            count += here
        length = np.sqrt(total[..., 0] * total[..., 0] + total[..., 1] * total[..., 1] + total[..., 2] * total[..., 2])
        take = ~baked & (count > 0) & (length > 0)
        image[take] = (0.5 * (total[take] / length[take, None]) + 0.5).astype(np.float32)
        baked = baked | take
    return image.astype(np.float32), baked


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_margin_follows_its_rule_where_neighbours_cancel(seed):
    target, source = opposite_squares(8, 64, seed)
    bare = nm.bake_normals(target, source, size=64, supersample=1, margin=0, diagnostics=False)
    full = nm.bake_normals(target, source, size=64, supersample=1, margin=8, diagnostics=False)
    image, baked = dilated_reference(bare.image, bare.coverage, 8)
    assert full.dilated > 0 and full.empty > 0  # some gap texels cancel for good
    assert np.array_equal(full.image, image)
    assert np.array_equal(full.coverage != nm.COVERAGE["empty"], baked)
