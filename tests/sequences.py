"""Mesh sequences made from known rigs, for the decomposition tests (no data files needed)."""
import numpy as np


def rotation(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def tube(segments: int, rings_per_segment: int = 4, sides: int = 10, length: float = 1.0, radius: float = 0.15):
    """A closed-ended tube along +Y split into `segments` pieces: positions (V, 3), triangles, each vertex's
    segment. Vertex rings are shared between segments only at the ends of the tube."""
    rings = segments * rings_per_segment + 1
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    y = np.linspace(0, length * segments, rings)
    positions = np.array([[radius * np.cos(a), h, radius * np.sin(a)] for h in y for a in angles])
    triangles = []
    for ring in range(rings - 1):
        for side in range(sides):
            a, b = ring * sides + side, ring * sides + (side + 1) % sides
            c, d = a + sides, b + sides
            triangles += [[a, c, b], [b, c, d]]
    bottom, top = len(positions), len(positions) + 1
    positions = np.vstack([positions, [[0, 0, 0], [0, y[-1], 0]]])
    for side in range(sides):
        a, b = side, (side + 1) % sides
        triangles.append([bottom, a, b])
        triangles.append([top, (rings - 1) * sides + b, (rings - 1) * sides + a])
    segment = np.minimum((positions[:, 1] / length).astype(int), segments - 1)
    return positions, np.array(triangles, np.int32), segment


def chain_poses(segments: int, frames: int, seed: int = 1, length: float = 1.0, bend: float = 0.8) -> np.ndarray:
    """(F, segments, 4, 4) rest->frame motions of a chain of hinged segments (joints at y = k * length)."""
    rng = np.random.default_rng(seed)
    motions = np.zeros((frames, segments, 4, 4))
    for frame in range(frames):
        world = np.eye(4)
        world[:3, :3] = rotation(rng.normal(size=3), rng.uniform(-0.3, 0.3))
        world[:3, 3] = rng.normal(scale=0.2, size=3)
        for bone in range(segments):
            joint = np.array([0.0, bone * length, 0.0])
            local = np.eye(4)
            if bone > 0:
                local[:3, :3] = rotation([1.0, 0.0, rng.uniform(-0.5, 0.5)], rng.uniform(-bend, bend))
            about_joint = np.eye(4)
            about_joint[:3, 3] = joint
            inverse = np.eye(4)
            inverse[:3, 3] = -joint
            world = world @ about_joint @ local @ inverse
            motions[frame, bone] = world
    return motions


def rigid_chain_sequence(segments: int = 3, frames: int = 10, seed: int = 1):
    """A tube whose segments move rigidly with a hinged chain: (frames (F, V, 3) with frame 0 the rest pose,
    triangles, segment of each vertex, motions (F, segments, 4, 4))."""
    positions, triangles, segment = tube(segments)
    motions = chain_poses(segments, frames, seed)
    motions[0] = np.eye(4)
    homogeneous = np.column_stack([positions, np.ones(len(positions))])
    sequence = np.einsum("fvij,vj->fvi", motions[:, segment, :3, :], homogeneous)
    return sequence, triangles, segment, motions
