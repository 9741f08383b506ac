"""Rigid skinning with seam reconstruction (Vasilakis 2008, section 4.4): every part of MESH follows its bone of the
rig `skinkit skeleton --out RIG.json` wrote, the gap between every two touching parts is closed by columns of QLERP
arc points joined into strips (and fans where three parts meet), and each frame is written as an .obj (the same
vertices and triangles every frame).
The motion comes from a keyframe file (joint angles, limits from --hierarchy refusing what breaks them, collisions
refusing what drives parts into each other) or from a folder of .Tmat files (one 4x3 matrix per part and frame:
three rows of the transposed rotation, then the translation, as libigl writes them; with parts from weights, part
bone_k takes the file's k-th block). JSON: per frame the seconds
of each gap step, the boundary edges left (0: watertight) and the points constructed. With --remove-sinking each
frame runs Algorithm 5 in full: the points sinking into the neighbouring part are removed and the holes filled
(removed_points, fallback per frame; the vertex count then varies). With --arcs conic the columns of a bent joint lie
on the thesis' conic middle-point arcs instead of the QLERP arcs (conic_columns per frame)."""
from __future__ import annotations

import json
import os
import time

import numpy as np

from ...model import SkinkitError
from ..outputs import written_atomically

HELP = "rigid skinning with seams closed at the joints (Vasilakis 2008)"
ARC_CHOICES = ("qlerp", "conic")  # skinkit.skeleton.seams.ARC_KINDS, named here so the parser loads no numpy code


def add_parser(subparsers, common):
    parser = subparsers.add_parser("rigid-skin", help=HELP, description=__doc__, parents=[common["json"]])
    parser.add_argument("mesh", metavar="MESH.obj")
    parser.add_argument("--parts", default="groups", help="as for `skinkit skeleton` (default groups)")
    parser.add_argument("--rig", required=True, help="RIG.json from `skinkit skeleton`")
    motion = parser.add_mutually_exclusive_group(required=True)
    motion.add_argument("--keyframes", help="a keyframe (clip) file of joint angles")
    motion.add_argument("--poses", help="a folder of .Tmat files, one per frame")
    parser.add_argument("--hierarchy", help="a hierarchy-and-limits file naming the parts (joint limits)")
    parser.add_argument("--frames", help="keyframe times A:B or A:B:STEP (default: the clip's range, step 1)")
    parser.add_argument("--steps", type=int, default=4, help="rings of arc points per seam (default 4)")
    parser.add_argument("--no-collisions", action="store_true", help="do not refuse colliding motions")
    parser.add_argument("--remove-sinking", action="store_true",
                        help="Algorithm 5 per frame: remove the points sinking into the next part and fill the holes "
                             "(the vertex count then changes per frame)")
    parser.add_argument("--arcs", choices=ARC_CHOICES, default="qlerp",
                        help="the arcs closing each seam: qlerp (about the joint, default) or conic (the thesis' "
                             "conic middle points where the joint bends)")
    parser.add_argument("--export-frames", required=True, metavar="DIR", help="where the frames' .obj files go")
    return parser


def read_rig(path: str):
    from ...skeleton import Skeleton

    try:
        with open(path, encoding="utf-8") as stream:
            data = json.load(stream)
    except OSError as error:
        raise SkinkitError(f"--rig {path}: {error.strerror}") from None
    except json.JSONDecodeError as error:
        raise SkinkitError(f"--rig {path}: not JSON ({error.msg}, line {error.lineno})") from None
    if not isinstance(data, dict) or "rig" not in data:
        raise SkinkitError(f"--rig {path}: no rig in it; write one with `skinkit skeleton ... --out RIG.json`")
    return Skeleton.from_dict(data["rig"])


def _block_of_part(part_names, block_count: int) -> np.ndarray:
    """Which .Tmat block drives each part: block k for a part named bone_k (parts from --parts weights:, whose
    bones without a dominant vertex are no parts), else the parts in order."""
    import re

    numbers = [re.fullmatch(r"bone_(\d+)", name) for name in part_names]
    if all(numbers) and max(int(m.group(1)) for m in numbers) < block_count:
        return np.array([int(m.group(1)) for m in numbers])
    return np.arange(len(part_names))


def read_tmat_folder(folder: str, part_count: int, part_names=None) -> tuple[list[str], np.ndarray]:
    """Frames (F, P, 4, 4) from .Tmat files in natural order (one block per part, or per bone_k as named)."""
    from ...meshio import read_text_lines

    if not os.path.isdir(folder):
        raise SkinkitError(f"--poses {folder}: not a folder")
    names = sorted((n for n in os.listdir(folder) if n.lower().endswith(".tmat")),
                   key=lambda n: [int(t) if t.isdigit() else t for t in __import__("re").split(r"(\d+)", n)])
    if not names:
        raise SkinkitError(f"--poses {folder}: no .Tmat files")
    frames = []
    for name in names:
        path = os.path.join(folder, name)
        try:
            values = np.array(" ".join(read_text_lines(path)).split(), dtype=np.float64)
        except ValueError:
            raise SkinkitError(f"{path}: a value is not a number") from None
        names_given = part_names is not None and values.size % 12 == 0 and values.size >= part_count * 12
        if values.size != part_count * 12 and not names_given:
            raise SkinkitError(f"{path}: {values.size} numbers; {part_count} parts need {part_count * 12}")
        blocks = values.reshape(-1, 4, 3)
        order = _block_of_part(part_names, len(blocks)) if part_names is not None else np.arange(part_count)
        if len(blocks) != part_count and order.max(initial=0) >= len(blocks) or len(order) != part_count:
            raise SkinkitError(f"{path}: {len(blocks)} transforms for {part_count} parts")
        blocks = blocks[order]
        world = np.tile(np.eye(4), (part_count, 1, 1))
        world[:, :3, :3] = np.transpose(blocks[:, :3, :], (0, 2, 1))
        world[:, :3, 3] = blocks[:, 3, :]
        frames.append(world)
    return names, np.array(frames)


def run(arguments) -> dict:
    from ...meshio import write_obj
    from ...skeleton import read_hierarchy
    from ...skeleton.animation import animate, read_keyframes
    from ...skeleton.seams import boundary_edges, prepare_seams, vertex_normals
    from ..inputs import frame_range
    from .skeleton import obj_parts, part_source

    source, weights_path = part_source(arguments.parts)
    parts = obj_parts(arguments.mesh, source, weights_path)
    skeleton = read_rig(arguments.rig)
    if tuple(skeleton.part_names) != tuple(parts.names):
        raise SkinkitError(f"--rig {arguments.rig}: its parts {list(skeleton.part_names)[:5]} are not the mesh's "
                           f"{list(parts.names)[:5]} (same --parts as for `skinkit skeleton`)")
    mesh = prepare_seams(parts, skeleton, arguments.steps)
    refused_limits = refused_collisions = None
    if arguments.keyframes:
        clip = read_keyframes(arguments.keyframes)
        times = (list(frame_range(arguments.frames)) if arguments.frames else
                 list(np.arange(clip.start, clip.end + 0.5, 1.0)))
        limits = read_hierarchy(arguments.hierarchy).reordered(parts.names).limits if arguments.hierarchy else None
        motion = animate(skeleton, clip, times, limits, check_collisions=not arguments.no_collisions)
        worlds, labels = motion.world, [f"{t:g}" for t in times]
        refused_limits, refused_collisions = motion.refused_limits, motion.refused_collisions
    else:
        labels, worlds = read_tmat_folder(arguments.poses, parts.part_count, parts.names)
    os.makedirs(arguments.export_frames, exist_ok=True)
    frames = []
    for index, world in enumerate(worlds):
        if arguments.remove_sinking or arguments.arcs != "qlerp":
            result = mesh.reconstruct(world, remove_sinking=arguments.remove_sinking, arcs=arguments.arcs)
            positions, triangles, seconds = result.positions, result.triangles, dict(result.seconds)
            extra = {"removed_points": result.removed_points, "fallback": result.fallback,
                     "constructed_points": mesh.constructed_points + result.fill_points,
                     "conic_columns": result.conic_columns}
        else:
            started = time.perf_counter()
            positions, triangles = mesh.positions(world), mesh.triangles
            added = time.perf_counter()
            vertex_normals(positions, triangles)
            seconds = {"add": added - started, "normals": time.perf_counter() - added}
            extra = {"constructed_points": mesh.constructed_points}
        checked_at = time.perf_counter()
        left = boundary_edges(triangles)
        seconds["check"] = time.perf_counter() - checked_at
        frame = {"frame": labels[index], "seconds": seconds, "boundary_edges": left, **extra}
        if refused_limits is not None:
            frame["refused_limits"] = [parts.names[p] for p in refused_limits[index]]
            frame["refused_collisions"] = [parts.names[p] for p in refused_collisions[index]]
        with written_atomically(os.path.join(arguments.export_frames, f"frame_{index + 1:04d}.obj")) as temporary:
            write_obj(temporary, positions, triangles)
        frames.append(frame)
    return {"frames": frames, "vertices": len(mesh.sources), "triangles": len(mesh.triangles),
            "triangulate_seconds": mesh.prepare_seconds, "ring_sizes": mesh.ring_sizes,
            "export_frames": os.path.abspath(arguments.export_frames)}
