"""Synthetic crowds for the runtime (skinkit.runtime): tube characters with a bone chain, their levels of detail
and geomorph data, and one frame of a crowd (culling, level selection, one batched skinning call) against the same
crowd at full detail. `skinkit runtime-bench` and bench/bench_runtime.py measure with these.

A character is a closed tube of rings along z, skinned to a chain of bones along its axis (each vertex on its
`influences` nearest joints, smooth weights). Level k + 1 keeps every other ring of level k (half the vertices and
influences, section 7.3), each dropped ring moving onto its neighbour; its epsilon is the largest distance, over
sampled poses, between a full-detail vertex and its image on the level, so the epsilons are measured, not modelled.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import runtime
from ._checks import FLAG, MAX_THREADS, THREADS, SkinkitError, as_real_array, checked, choice, count, real
from .metrics import PoseStatistics
from .model import AnimationSpaceModel

__all__ = ["Character", "tube_character", "Crowd", "random_crowd", "Camera", "look_camera", "random_camera",
           "FramePlan", "plan_frame", "measure_crowd", "timed_seconds", "synthetic_mesh", "skin_seconds", "bytes_moved",
           "fixed_bytes_moved", "triad_bandwidth", "LAYOUTS"]

SEGMENTS = 48      # vertices per ring
HEIGHT = 1.8       # metres: a person-sized tube
RADIUS = 0.25
MAX_ANGLE = 0.6    # radians per joint and axis in sampled poses
#: Bounds of the synthetic scenes' sizes and the timing loops: far above a benchmark's, far below a hang.
MAX_VERTICES = 2**24
MAX_BONES = 1024
MAX_LEVELS = 16
MAX_INSTANCES = 2**16
MAX_REPEATS = 1000
MAX_ELEMENTS = 2**28
SEED = count(0, 2**63 - 1)
REPEATS = count(1, MAX_REPEATS)
KERNEL = choice(tuple(runtime.KERNELS))
#: The pack layouts a crowd is skinned from: "csr" (RuntimePack) or "fixed" (its FixedPack, K slots per vertex).
LAYOUTS = ("csr", "fixed")


def callable_without_arguments(value, name: str):
    if not callable(value):
        raise SkinkitError(f"{name}: expected a function called with no arguments, got {type(value).__name__}")
    return value


@dataclass
class Character:
    """One character's levels: level k is pack mesh k; to_coarser[k] maps level k's vertices to level k + 1's."""
    pack: runtime.RuntimePack
    to_coarser: list[np.ndarray]
    joints: np.ndarray          # (B,) joint heights, joints[0] = 0 for the root
    sphere: np.ndarray          # (4,) object-space culling sphere (section 7.2)

    @property
    def bone_count(self) -> int:
        return self.pack.bone_count

    @property
    def vertex_count(self) -> int:
        return int(self.pack.vertex_counts[0])


def _level_model(rings: np.ndarray, joints: np.ndarray, influences: int) -> AnimationSpaceModel:
    """Animation-space model of a tube with the given ring heights: p_j = w_j (v - joint_j, 1) (eq. 3.1 with rest
    frames that are translations)."""
    angles = np.linspace(0, 2 * np.pi, SEGMENTS, endpoint=False)
    z = np.repeat(rings, SEGMENTS)
    positions = np.stack([RADIUS * np.cos(np.tile(angles, len(rings))), RADIUS * np.sin(np.tile(angles, len(rings))),
                          z], axis=1)
    centres = (joints[1:] + np.append(joints[2:], HEIGHT)) / 2  # midpoints of bones 1 .. B-1
    distance = np.abs(z[:, None] - centres[None])
    nearest = np.argsort(distance, axis=1, kind="stable")[:, :influences]
    weights = np.exp(-(np.take_along_axis(distance, nearest, 1) / (HEIGHT / len(joints))) ** 2)
    weights /= weights.sum(axis=1, keepdims=True)
    bones = np.sort(nearest, axis=1)
    weights = np.take_along_axis(weights, np.argsort(nearest, axis=1), 1)
    bones = bones + 1  # bones 1 .. B-1 carry the mesh; 0 is the root
    coordinates = np.zeros((len(z), influences, 4))
    coordinates[..., :3] = weights[..., None] * (positions[:, None, :] - np.stack(
        [np.zeros_like(bones, float), np.zeros_like(bones, float), joints[bones]], axis=-1))
    coordinates[..., 3] = weights
    offsets = np.arange(0, influences * len(z) + 1, influences, dtype=np.int32)
    return AnimationSpaceModel.create(offsets, bones.reshape(-1).astype(np.int32), coordinates.reshape(-1, 4),
                                      len(joints))


def local_frames(angles: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(S, B, 4, 4) joint frames L_j: the offset from the parent joint, then rotations about x and y by angles
    (S, B, 2); L_0 = I."""
    samples, bones = angles.shape[:2]
    local = np.tile(np.eye(4), (samples, bones, 1, 1))
    cx, sx, cy, sy = np.cos(angles[..., 0]), np.sin(angles[..., 0]), np.cos(angles[..., 1]), np.sin(angles[..., 1])
    rx = np.zeros((samples, bones, 3, 3))
    rx[..., 0, 0], rx[..., 1, 1], rx[..., 1, 2], rx[..., 2, 1], rx[..., 2, 2] = 1, cx, -sx, sx, cx
    ry = np.zeros((samples, bones, 3, 3))
    ry[..., 1, 1], ry[..., 0, 0], ry[..., 0, 2], ry[..., 2, 0], ry[..., 2, 2] = 1, cy, sy, -sy, cy
    local[..., :3, :3] = rx @ ry
    local[:, 1:, 2, 3] = np.diff(joints)
    local[:, 0] = np.eye(4)
    return local


def world_frames(local: np.ndarray) -> np.ndarray:
    """G_j = G_{j-1} L_j down the chain (S, B, 4, 4)."""
    world = local.copy()
    for j in range(2, local.shape[1]):
        world[:, j] = world[:, j - 1] @ local[:, j]
    return world


def random_poses(rng, count: int, joints: np.ndarray) -> np.ndarray:
    angles = rng.uniform(-MAX_ANGLE, MAX_ANGLE, (count, len(joints), 2))
    return world_frames(local_frames(angles, joints))


def _morph(fine: AnimationSpaceModel, coarse: AnimationSpaceModel, mapped: np.ndarray):
    """p^l and p^{l+1}(mapped) - p^l on the union of both bone sets per fine vertex (dense over the few bones)."""
    bones = fine.bone_count
    dense_fine = np.zeros((fine.vertex_count, bones, 4))
    dense_coarse = np.zeros((coarse.vertex_count, bones, 4))
    dense_fine[fine.vertex_of_each_influence(), fine.bones] = fine.coordinates
    dense_coarse[coarse.vertex_of_each_influence(), coarse.bones] = coarse.coordinates
    target = dense_coarse[mapped]
    rows, columns = np.nonzero(np.any(dense_fine != 0, axis=2) | np.any(target != 0, axis=2))
    offsets = np.zeros(fine.vertex_count + 1, np.int32)
    np.cumsum(np.bincount(rows, minlength=fine.vertex_count), out=offsets[1:])
    p = dense_fine[rows, columns]
    return {"offsets": offsets, "bones": columns.astype(np.int32), "coordinates": p,
            "delta": target[rows, columns] - p}


def _evaluate(model: AnimationSpaceModel, poses: np.ndarray) -> np.ndarray:
    return np.asarray(model.evaluate(poses)).reshape(len(poses), model.vertex_count, 3)


@checked(vertices=count(1, MAX_VERTICES), bones=count(2, MAX_BONES), influences=count(1, MAX_BONES),
         levels=count(1, MAX_LEVELS), seed=SEED)
def tube_character(vertices: int, bones: int = 16, influences: int = 4, levels: int = 4, seed: int = 0) -> Character:
    """A tube of about `vertices` vertices on a chain of `bones` bones (root included) with `levels` levels."""
    if vertices < 4 * SEGMENTS or bones < 2 or not 1 <= influences <= bones - 1 or levels < 1:
        raise SkinkitError(f"tube_character: needs vertices >= {4 * SEGMENTS}, bones >= 2, 1 <= influences < bones "
                           f"and levels >= 1")
    rng = np.random.default_rng(seed)
    joints = np.linspace(0, HEIGHT, bones, endpoint=False)
    ring_heights = [np.linspace(0, HEIGHT, max(vertices // SEGMENTS, 2))]
    ring_maps = []
    while len(ring_heights) < levels and len(ring_heights[-1]) >= 4:
        fine = ring_heights[-1]
        kept = np.unique(np.append(np.arange(0, len(fine), 2), len(fine) - 1))
        ring_maps.append(np.searchsorted(kept, np.arange(len(fine))))  # a dropped ring moves onto its next ring
        ring_heights.append(fine[kept])
    models = [_level_model(rings, joints, influences) for rings in ring_heights]
    segment = np.arange(SEGMENTS)
    to_coarser = [(ring_map[:, None] * SEGMENTS + segment[None]).reshape(-1) for ring_map in ring_maps]
    poses = random_poses(rng, 16, joints)
    full = _evaluate(models[0], poses)
    chained = np.arange(models[0].vertex_count)
    epsilons, meshes = [0.0], []
    for level, mapped in enumerate(to_coarser):
        meshes.append(_morph(models[level], models[level + 1], mapped))
        chained = mapped[chained]
        deviation = np.linalg.norm(full - _evaluate(models[level + 1], poses)[:, chained], axis=2).max()
        epsilons.append(max(float(deviation), epsilons[-1]))
    last = models[-1]
    meshes.append({"offsets": last.offsets, "bones": last.bones, "coordinates": last.coordinates})
    pack = runtime.RuntimePack.from_meshes(meshes, bones, epsilons)
    parents = np.arange(-1, bones - 1, dtype=np.int32)  # a chain: bone j's parent is j - 1
    statistics = PoseStatistics.from_local_samples(parents, local_frames(
        rng.uniform(-MAX_ANGLE, MAX_ANGLE, (64, bones, 2)), joints))
    sphere = runtime.culling_sphere(models[0], statistics)
    return Character(pack, to_coarser, joints, sphere)


@dataclass
class Camera:
    position: np.ndarray
    forward: np.ndarray
    view_projection: np.ndarray  # (4, 4) row-major OpenGL
    horizontal_fov: float
    width: int
    height: int

    def pixels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) pixel coordinates of world points (N, 3), and which lie in front of the camera."""
        points = as_real_array(points, "points", shape=(None, 3))
        clip = np.c_[points, np.ones(len(points))] @ self.view_projection.T
        in_front = clip[:, 3] > 1e-6
        ndc = clip[:, :2] / np.where(in_front, clip[:, 3], 1.0)[:, None]
        return (ndc + 1) / 2 * [self.width, self.height], in_front


@checked(horizontal_fov=real(above=0, maximum=np.pi), width=count(1, 2**16), height=count(1, 2**16),
         near=real(above=0), far=real(above=0))
def look_camera(position, target, horizontal_fov=np.radians(60), width=1920, height=1080, near=0.1, far=500.0):
    position, target = as_real_array(position, "position", shape=(3,)), as_real_array(target, "target", shape=(3,))
    if not far > near:  # equal planes divide by zero below
        raise SkinkitError(f"far: must be beyond near ({near!r}), got {far!r}")
    forward = target - position
    distance = float(np.linalg.norm(forward))
    if not 0 < distance < np.inf:
        raise SkinkitError(f"target: must differ from position (and be finitely far), got {target.tolist()}")
    forward /= distance
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if not np.linalg.norm(right) > 1e-12:
        raise SkinkitError("target: straight above or below position: the camera's up (+z) is undefined")
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, up, -forward
    view[:3, 3] = -view[:3, :3] @ position
    fx = 1 / np.tan(horizontal_fov / 2)
    projection = np.zeros((4, 4))
    projection[0, 0], projection[1, 1] = fx, fx * width / height
    projection[2, 2], projection[2, 3] = -(far + near) / (far - near), -2 * far * near / (far - near)
    projection[3, 2] = -1
    return Camera(position, forward, projection @ view, float(horizontal_fov), width, height)


@checked(rng=np.random.Generator, extent=real(above=0, maximum=1e6))
def random_camera(rng, extent: float) -> Camera:
    """Eye height on the crowd's square [-extent, extent]^2, looking at a random point of it."""
    position = np.r_[rng.uniform(-extent, extent, 2), 1.7]
    target = np.r_[rng.uniform(-extent, extent, 2), 0.9]
    while np.linalg.norm(target[:2] - position[:2]) < 1.0:
        target[:2] = rng.uniform(-extent, extent, 2)
    return look_camera(position, target)


@dataclass
class Crowd:
    """Instances of characters on the ground: all characters' levels in one pack, so a frame is one call."""
    characters: list[Character]
    pack: runtime.RuntimePack
    first_mesh: np.ndarray      # (C,) the pack mesh of each character's level 0
    character: np.ndarray       # (I,) which character each instance is
    placement: np.ndarray       # (I, 4, 4) object-to-world rigid motions
    level_counts: np.ndarray    # (C,)

    @property
    def instance_count(self) -> int:
        return len(self.character)

    def spheres(self) -> np.ndarray:
        """(I, 4) world-space culling spheres (rigid placements keep the radius)."""
        local = np.stack([c.sphere for c in self.characters])[self.character]
        centres = np.einsum("nij,nj->ni", self.placement[:, :3, :3], local[:, :3]) + self.placement[:, :3, 3]
        return np.c_[centres, local[:, 3]].astype(np.float32)

    def epsilons(self) -> np.ndarray:
        """(I, L) each instance's level epsilons, +inf padding shorter chains."""
        width = int(self.level_counts.max())
        table = np.full((len(self.characters), width), np.inf, np.float32)
        for index, c in enumerate(self.characters):
            table[index, :c.pack.mesh_count] = c.pack.epsilons
        return table[self.character]

    def matrices(self, poses: list[np.ndarray]) -> np.ndarray:
        """(I, B, 12) world bone matrices W G_j from per-instance poses (B, 4, 4)."""
        if not isinstance(poses, (list, tuple)) or len(poses) != self.instance_count:
            raise SkinkitError(f"poses: expected a list of {self.instance_count} pose arrays (B, 4, 4), one per "
                               f"instance, got {type(poses).__name__}")
        stacked = np.stack([as_real_array(p, f"poses[{i}]", shape=(None, 4, 4)) for i, p in enumerate(poses)]) \
            if len({np.shape(p) for p in poses}) == 1 else None
        if stacked is None:
            raise SkinkitError("poses: every instance needs the same number of bones")
        return runtime.bone_matrices(np.einsum("nij,nbjk->nbik", self.placement, stacked))


def vertex_range(value, name: str) -> tuple[int, int]:
    """(fewest, most) vertices of a character kind."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise SkinkitError(f"{name}: expected (fewest, most) vertices, got {type(value).__name__}")
    low, high = (count(1, MAX_VERTICES)(v, f"{name}[{i}]") for i, v in enumerate(value))
    if low > high:
        raise SkinkitError(f"{name}: fewest {low} is more than most {high}")
    return low, high


@checked(count=count(1, MAX_INSTANCES), vertex_range=vertex_range, kinds=count(1, MAX_BONES),
         bones=count(2, MAX_BONES), influences=count(1, MAX_BONES), levels=count(1, MAX_LEVELS),
         extent=real(above=0, maximum=1e6), seed=SEED)
def random_crowd(count: int = 100, vertex_range=(10_000, 50_000), kinds: int = 5, bones: int = 16,
                 influences: int = 4, levels: int = 4, extent: float = 40.0, seed: int = 0) -> Crowd:
    """`count` instances of `kinds` characters whose vertex counts spread over vertex_range, placed at random on
    [-extent, extent]^2 and turned at random."""
    rng = np.random.default_rng(seed)
    sizes = np.linspace(vertex_range[0], vertex_range[1], kinds).astype(int)
    characters = [tube_character(int(v), bones, influences, levels, seed + i) for i, v in enumerate(sizes)]
    flat = [_pack_mesh(c.pack, m) for c in characters for m in range(c.pack.mesh_count)]
    epsilons = np.concatenate([c.pack.epsilons for c in characters])
    pack = runtime.RuntimePack.from_meshes(flat, bones, epsilons)
    first = np.cumsum([0] + [c.pack.mesh_count for c in characters[:-1]]).astype(np.int32)
    character = rng.integers(0, kinds, count)
    angle = rng.uniform(0, 2 * np.pi, count)
    placement = np.tile(np.eye(4), (count, 1, 1))
    placement[:, 0, 0], placement[:, 0, 1], placement[:, 1, 0], placement[:, 1, 1] = (
        np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle))
    placement[:, :2, 3] = rng.uniform(-extent, extent, (count, 2))
    return Crowd(characters, pack, first, character, placement,
                 np.array([c.pack.mesh_count for c in characters]))


def _pack_mesh(pack: runtime.RuntimePack, mesh: int) -> dict:
    """Mesh `mesh` of a pack back as from_meshes takes it."""
    v0, v1 = pack.mesh_starts[mesh], pack.mesh_starts[mesh + 1]
    k0, k1 = pack.offsets[v0], pack.offsets[v1]
    return {"offsets": pack.offsets[v0:v1 + 1] - k0, "bones": pack.bones[k0:k1],
            "coordinates": pack.positions[k0:k1, :4], "delta": pack.positions[k0:k1, 4:]}


@checked(elements=count(1, MAX_ELEMENTS), threads=count(1, MAX_THREADS), repeats=REPEATS)
def triad_bandwidth(elements: int = 20_000_000, threads: int = 1, repeats: int = 7) -> float:
    """A STREAM-style triad a = b + s c in float64 over `threads` threads (numpy releases the GIL), as numpy does it:
    two passes (a = s c, then a += b), so 5 arrays' bytes are counted per element, as they move. The best of
    `repeats`, in bytes per second."""
    import time
    from concurrent.futures import ThreadPoolExecutor
    a, b, c = np.empty(elements), np.ones(elements), np.full(elements, 2.0)
    bounds = np.linspace(0, elements, threads + 1).astype(int)

    def chunk(index):
        lo, hi = bounds[index], bounds[index + 1]
        np.multiply(c[lo:hi], 3.0, out=a[lo:hi])
        np.add(a[lo:hi], b[lo:hi], out=a[lo:hi])

    best = np.inf
    with ThreadPoolExecutor(threads) as pool:
        for _ in range(repeats + 1):
            started = time.perf_counter()
            list(pool.map(chunk, range(threads)))
            best = min(best, time.perf_counter() - started)
    return 5 * 8 * elements / best


# ---- measuring ---------------------------------------------------------------------------------------------------

@checked(call=callable_without_arguments, repeats=REPEATS, best=FLAG)
def timed_seconds(call, repeats: int, best: bool = False) -> float:
    """The median (or, with best, the minimum: what a machine shared with other work still shows of the code's own
    cost) of `repeats` timed calls, after one untimed call that pages in the outputs."""
    import time
    call()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        times.append(time.perf_counter() - started)
    return float(np.min(times) if best else np.median(times))


@dataclass
class FramePlan:
    visible: np.ndarray   # (I,) bool
    levels: np.ndarray    # (visible,) float32
    meshes: np.ndarray    # (visible,) pack meshes
    fractions: np.ndarray


@checked(crowd=Crowd, camera=Camera, pixel_tolerance=real(above=0))
def plan_frame(crowd: Crowd, camera: Camera, pixel_tolerance: float, spheres=None, epsilons=None) -> FramePlan:
    """Culling (section 7.2) and level selection (eq. 7.2) for every instance."""
    spheres = crowd.spheres() if spheres is None else as_real_array(spheres, "spheres", np.float32,
                                                                     (crowd.instance_count, 4))
    epsilons = crowd.epsilons() if epsilons is None else as_real_array(epsilons, "epsilons", np.float32,
                                                                       (crowd.instance_count, None))
    visible = runtime.cull(spheres, runtime.frustum_planes(camera.view_projection))
    levels = runtime.select_levels(spheres[visible], epsilons[visible], camera.position, camera.forward,
                                   camera.horizontal_fov, camera.width, pixel_tolerance)
    base = np.floor(levels).astype(np.int32)
    meshes = crowd.first_mesh[crowd.character[visible]] + base
    return FramePlan(visible, levels, meshes.astype(np.int32), (levels - base).astype(np.float32))


def pixel_error(crowd: Crowd, camera: Camera, plan: FramePlan, full: np.ndarray, drawn: np.ndarray,
                full_starts: np.ndarray, drawn_starts: np.ndarray) -> float:
    """The largest screen distance in pixels between a visible instance's full-detail vertex and its image on the
    drawn level (geomorphed), over vertices in front of the camera."""
    worst = 0.0
    for slot, instance in enumerate(np.flatnonzero(plan.visible)):
        character = crowd.characters[crowd.character[instance]]
        chained = np.arange(character.vertex_count)
        for level in range(int(np.floor(plan.levels[slot]))):
            chained = character.to_coarser[level][chained]
        reference = full[full_starts[instance]:full_starts[instance + 1]]
        image = drawn[drawn_starts[slot]:drawn_starts[slot + 1]][chained]
        a, front_a = camera.pixels(reference)
        b, front_b = camera.pixels(image)
        front = front_a & front_b
        if front.any():
            worst = max(worst, float(np.linalg.norm(a[front] - b[front], axis=1).max()))
    return worst


def cameras(value, name: str) -> list:
    """A non-empty list of Cameras."""
    if not isinstance(value, (list, tuple)) or not value or not all(isinstance(c, Camera) for c in value):
        raise SkinkitError(f"{name}: expected a non-empty list of skinkit.crowd.Camera, got {type(value).__name__}")
    return list(value)


@checked(crowd=Crowd, cameras=cameras, pixel_tolerance=real(above=0), kernel=KERNEL, threads=THREADS, repeats=REPEATS,
         seed=SEED, best=FLAG, layout=choice(LAYOUTS))
def measure_crowd(crowd: Crowd, cameras: list[Camera], pixel_tolerance: float = 1.0, kernel: str = "auto",
                  threads: int = 0, repeats: int = 5, seed: int = 0, best: bool = False, layout: str = "csr") -> dict:
    """Per random camera: the frame with culling + level selection + one batched skinning call against every
    instance skinned at full detail (both with preallocated outputs); medians (best: minima) over repeats, then
    medians over cameras. layout "fixed" skins from the crowd pack's FixedPack (the same meshes and geomorphs)."""
    pack = crowd.pack if layout == "csr" else crowd.pack.fixed()
    rng = np.random.default_rng(seed)
    poses = [random_poses(rng, 1, crowd.characters[c].joints)[0] for c in crowd.character]
    matrices = crowd.matrices(poses)
    full_meshes = crowd.first_mesh[crowd.character]
    full_counts = crowd.pack.vertex_counts[full_meshes]
    full_starts = np.concatenate(([0], np.cumsum(full_counts)))
    out_full = np.empty((int(full_starts[-1]), 3), np.float32)
    out_lod = np.empty_like(out_full)
    spheres, epsilons = crowd.spheres(), crowd.epsilons()
    zeros = np.zeros(crowd.instance_count, np.float32)
    rows = []
    for camera in cameras:
        def full_frame():
            return runtime.skin(pack, full_meshes, zeros, matrices, kernel=kernel, threads=threads, out=out_full)

        def lod_frame():
            plan = plan_frame(crowd, camera, pixel_tolerance, spheres, epsilons)
            return plan, runtime.skin(pack, plan.meshes, plan.fractions, matrices[plan.visible], kernel=kernel,
                                      threads=threads, out=out_lod)

        full_seconds = timed_seconds(full_frame, repeats, best)
        lod_seconds = timed_seconds(lod_frame, repeats, best)
        full_result = full_frame()
        plan, drawn = lod_frame()
        drawn_vertices = int(drawn.output_starts[-1])
        rows.append({"full_ms": 1e3 * full_seconds, "lod_ms": 1e3 * lod_seconds, "speedup": full_seconds / lod_seconds,
                     "visible": int(plan.visible.sum()), "mean_level": float(plan.levels.mean()) if len(plan.levels) else 0.0,
                     "drawn_vertices": drawn_vertices, "full_vertices": int(full_starts[-1]),
                     "drawn_influences": int(crowd.pack.influence_counts()[plan.meshes].sum()),
                     "pixel_error": pixel_error(crowd, camera, plan, full_result.positions, drawn.positions,
                                                full_starts, drawn.output_starts)})
    summary = {key: float(np.median([r[key] for r in rows])) for key in rows[0]}
    return {"frames": rows, "median": summary, "max_pixel_error": max(r["pixel_error"] for r in rows),
            "pixel_tolerance": pixel_tolerance}


@checked(vertices=count(1, MAX_VERTICES), influences=count(1, MAX_BONES), bones=count(1, MAX_BONES), seed=SEED)
def synthetic_mesh(vertices: int, influences: int, bones: int = 24, seed: int = 0) -> runtime.RuntimePack:
    """One morphing mesh of random data, `influences` per vertex, for throughput runs."""
    rng = np.random.default_rng(seed)
    count = vertices * influences
    return runtime.RuntimePack.from_meshes([{
        "offsets": np.arange(0, count + 1, influences, dtype=np.int32),
        "bones": rng.integers(0, bones, count).astype(np.int32),
        "coordinates": rng.normal(size=(count, 4)), "delta": 0.1 * rng.normal(size=(count, 4))}], bones)


@checked(pack=runtime.runtime_pack, instances=count(1, MAX_INSTANCES), kernel=KERNEL, threads=THREADS,
         repeats=REPEATS, seed=SEED, best=FLAG, fraction=real(minimum=0, maximum=1), tangents=FLAG)
def skin_seconds(pack, instances: int, kernel: str, threads: int, repeats: int = 5, seed: int = 0,
                 best: bool = False, fraction: float = 0.5, tangents: bool = False) -> float:
    """Seconds of one batched call skinning `instances` instances of the pack's mesh 0 (a RuntimePack or a
    FixedPack; positions reused) at the geomorph fraction, with or without both tangents, as timed_seconds
    measures them."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (instances, pack.bone_count, 1, 1))
    poses[:, :, :3, :] = rng.uniform(-1, 1, (instances, pack.bone_count, 3, 4))
    matrices = runtime.bone_matrices(poses)
    meshes = np.zeros(instances, np.int32)
    fractions = np.full(instances, fraction, np.float32)
    out = np.empty((instances * int(pack.vertex_counts[0]), 3), np.float32)
    return timed_seconds(lambda: runtime.skin(pack, meshes, fractions, matrices, tangents=tangents, kernel=kernel,
                                              threads=threads, out=out), repeats, best)


@checked(vertices=count(0, MAX_VERTICES), influences=count(0, MAX_VERTICES * MAX_BONES))  # all of them
def bytes_moved(vertices: int, influences: int) -> int:
    """What algorithm 1 must move through memory: per influence (p, dp) 32 bytes and a bone index 4, per vertex an
    offset 4 and the output written 12 (read for ownership, then written: 24)."""
    return influences * 36 + vertices * 28


@checked(vertices=count(0, MAX_VERTICES), slots=count(2, runtime.MAX_FIXED_SLOTS), floats_per_slot=count(4, 8),
         streams=count(1, 3))
def fixed_bytes_moved(vertices: int, slots: int, floats_per_slot: int, streams: int = 1) -> int:
    """The same for the fixed-K layout: per slot a 16-bit bone and 4 bytes per float of each stream, per vertex 24
    bytes per stream's output (floats_per_slot 4 or 8; streams 1, positions only, to 3, with both tangents)."""
    return vertices * (slots * (2 + 4 * floats_per_slot * streams) + 24 * streams)
