"""Keyframing and forward kinematics for a part skeleton (Vasilakis 2008, sections 4.2-4.3): the keyframe ("CLIP")
file, per-channel cubic Hermite spans with flat / linear / smooth tangents and five extrapolation modes, QT-pair
forward kinematics in the core, and motion acceptance: a joint whose angle leaves its limits keeps its last
accepted angles, and a joint whose motion makes two parts collide (sphere broad phase, oriented-box separating axes;
a parent and its child excepted) is turned back.

Encodings the thesis leaves open (digest section 5): extrapolation modes and tangent rules are written by name
(`constant linear cycle cycle_offset bounce`, `flat linear smooth`) or by their index in those lists; channel id
3 k + a is part k's angle about axis a (X, Y, Z), in degrees, absolute (not per-frame deltas).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from .. import _core
from ..meshio import read_text_lines
from .._checks import FLAG, INPUT_FILE, OUTPUT_FILE, as_index_array, as_real_array, checked, count, real
from ..model import SkinkitError
from .extract import Skeleton as BoneSkeleton

__all__ = ["EXTRAPOLATIONS", "TANGENTS", "Channel", "Keyframes", "read_keyframes", "write_keyframes", "Motion",
           "joint_frame", "pose", "collision_candidates", "CollisionTest", "find_collisions",
           "collisions", "animate"]

EXTRAPOLATIONS = ("constant", "linear", "cycle", "cycle_offset", "bounce")
TANGENTS = ("flat", "linear", "smooth")


@dataclass
class Channel:
    """Keys (times ascending, values), their in/out tangent rules, and the extrapolation before and after."""
    times: np.ndarray
    values: np.ndarray
    tangent_in: list[str]
    tangent_out: list[str]
    extrapolate: tuple[str, str] = ("constant", "constant")

    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """Incoming and outgoing slopes (value per unit time) at each key from its rules."""
        t, f, n = self.times, self.values, len(self.times)
        incoming, outgoing = np.zeros(n), np.zeros(n)
        for k in range(n):
            back = (f[k] - f[k - 1]) / (t[k] - t[k - 1]) if k > 0 else None
            ahead = (f[k + 1] - f[k]) / (t[k + 1] - t[k]) if k + 1 < n else None
            smooth = ((f[k + 1] - f[k - 1]) / (t[k + 1] - t[k - 1]) if 0 < k < n - 1 else
                      (back if back is not None else ahead if ahead is not None else 0.0))
            linear_in = back if back is not None else (ahead or 0.0)
            linear_out = ahead if ahead is not None else (back or 0.0)
            incoming[k] = {"flat": 0.0, "linear": linear_in, "smooth": smooth}[self.tangent_in[k]]
            outgoing[k] = {"flat": 0.0, "linear": linear_out, "smooth": smooth}[self.tangent_out[k]]
        return incoming, outgoing

    def evaluate(self, times) -> np.ndarray:
        times = as_real_array(times, "times")
        t, f = self.times, self.values
        if len(t) == 1:
            return np.full(times.shape, f[0])
        incoming, outgoing = self.slopes()
        span, change = t[-1] - t[0], f[-1] - f[0]
        out = np.empty(times.shape)
        for index, time in np.ndenumerate(times):
            offset = 0.0
            mode = self.extrapolate[0] if time < t[0] else self.extrapolate[1] if time > t[-1] else None
            if mode == "constant":
                out[index] = f[0] if time < t[0] else f[-1]
                continue
            if mode == "linear":
                out[index] = f[0] + incoming[0] * (time - t[0]) if time < t[0] else f[-1] + outgoing[-1] * (time - t[-1])
                continue
            if mode in ("cycle", "cycle_offset"):
                cycles = np.floor((time - t[0]) / span)
                time, offset = time - cycles * span, (cycles * change if mode == "cycle_offset" else 0.0)
            elif mode == "bounce":
                phase = np.mod(time - t[0], 2 * span)
                time = t[0] + (phase if phase <= span else 2 * span - phase)
            k = int(np.clip(np.searchsorted(t, time, side="right") - 1, 0, len(t) - 2))
            length = t[k + 1] - t[k]
            s = (time - t[k]) / length
            p1, p2, m1, m2 = f[k], f[k + 1], outgoing[k] * length, incoming[k + 1] * length
            h = ((2 * s - 3) * s * s + 1, (-2 * s + 3) * s * s, ((s - 2) * s + 1) * s, (s - 1) * s * s)
            out[index] = h[0] * p1 + h[1] * p2 + h[2] * m1 + h[3] * m2 + offset
        return out


@dataclass
class Keyframes:
    """The clip's time range and its channels by id."""
    start: float
    end: float
    channels: dict[int, Channel] = field(default_factory=dict)

    @checked(time=real(), part_count=count(0, 2**16))
    def angles(self, time: float, part_count: int) -> np.ndarray:
        """(P, 3) degrees at `time`; a channel not in the clip is 0."""
        out = np.zeros((part_count, 3))
        for identifier, channel in self.channels.items():
            if identifier < 3 * part_count:
                out[identifier // 3, identifier % 3] = float(channel.evaluate(time))
        return out


def _choice(token: str, names: tuple[str, ...], what: str, where: str) -> str:
    if token.isdigit() and int(token) < len(names):
        return names[int(token)]
    if token.lower() in names:
        return token.lower()
    raise SkinkitError(f"{where}: {what} {token!r} is not one of {', '.join(names)} (or 0-{len(names) - 1})")


@checked(path=INPUT_FILE)
def read_keyframes(path: str) -> Keyframes:
    """Parses a keyframe file (thesis Fig. 4.6; keywords in any case); errors name the line."""
    tokens = [(n, t) for n, line in enumerate(read_text_lines(path), 1)
              for t in re.sub(r"([{}])", r" \1 ", line).split()]
    position = 0

    def take(expected=None):
        nonlocal position
        if position >= len(tokens):
            raise SkinkitError(f"{path}: ended early" + (f", expected {expected!r}" if expected else ""))
        number, token = tokens[position]
        position += 1
        if expected is not None and token.lower() != expected:
            raise SkinkitError(f"{path}:{number}: expected {expected!r}, got {token!r}")
        return number, token

    def number(what):
        line, token = take()
        try:
            value = float(token)
        except ValueError:
            raise SkinkitError(f"{path}:{line}: {what} {token!r} is not a number") from None
        if not np.isfinite(value):
            raise SkinkitError(f"{path}:{line}: {what} is not finite")
        return value

    take("animation"), take("{"), take("range")
    clip = Keyframes(number("range start"), number("range end"))
    take("numchannels")
    count = int(number("numchannels"))
    for _ in range(count):
        take("channel")
        line, _ = tokens[position]
        identifier = int(number("channel id"))
        if identifier < 0 or identifier in clip.channels:
            raise SkinkitError(f"{path}:{line}: channel id {identifier} is negative or repeated")
        take("{"), take("extrapolate")
        where = f"{path}:{tokens[position][0]}"
        modes = (_choice(take()[1], EXTRAPOLATIONS, "extrapolation", where),
                 _choice(take()[1], EXTRAPOLATIONS, "extrapolation", where))
        take("keys")
        key_count = int(number("keys"))
        if key_count < 1:
            raise SkinkitError(f"{path}:{line}: channel {identifier} has no keys")
        take("{")
        times, values, rules_in, rules_out = [], [], [], []
        for _ in range(key_count):
            where = f"{path}:{tokens[position][0]}"
            times.append(number("key time"))
            values.append(number("key value"))
            rules_in.append(_choice(take()[1], TANGENTS, "tangent", where))
            rules_out.append(_choice(take()[1], TANGENTS, "tangent", where))
        if np.any(np.diff(times) <= 0):
            raise SkinkitError(f"{path}:{line}: channel {identifier}'s key times do not increase")
        take("}"), take("}")
        clip.channels[identifier] = Channel(np.array(times), np.array(values), rules_in, rules_out, modes)
    take("}")
    return clip


@checked(path=OUTPUT_FILE, clip=Keyframes)
def write_keyframes(path: str, clip: Keyframes) -> str:
    lines = ["animation {", f"  range {clip.start:g} {clip.end:g}", f"  numchannels {len(clip.channels)}"]
    for identifier, channel in sorted(clip.channels.items()):
        lines += [f"  channel {identifier} {{", f"    extrapolate {channel.extrapolate[0]} {channel.extrapolate[1]}",
                  f"    keys {len(channel.times)} {{"]
        lines += [f"      {t!r} {v!r} {a} {b}" for t, v, a, b in
                  zip(channel.times.tolist(), channel.values.tolist(), channel.tangent_in, channel.tangent_out)]
        lines += ["    }", "  }"]
    lines.append("}")
    temporary = f"{path}.partial"
    with open(temporary, "w", encoding="utf-8") as stream:
        stream.write("\n".join(lines) + "\n")
    os.replace(temporary, path)
    return path


@checked(skeleton=BoneSkeleton)
def joint_frame(skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Each part's joint (its opening with its parent; the root's root point) and parent axis (joint -> parent's
    KC; +z for the root), as sk_forward_kinematics takes them."""
    joints = skeleton.positions[skeleton.part_joints]
    axes = np.tile([0.0, 0.0, 1.0], (len(joints), 1))
    for p, parent in enumerate(skeleton.part_parents.tolist()):
        if parent >= 0:
            axes[p] = skeleton.kernel_centroids[parent] - joints[p]
    return np.ascontiguousarray(joints), axes


@checked(skeleton=BoneSkeleton)
def pose(skeleton, angles, root_frame=None) -> np.ndarray:
    """World frames (P, 4, 4) for joint angles (P, 3) in degrees."""
    joints, axes = joint_frame(skeleton)
    angles = as_real_array(angles, "angles", shape=(len(joints), 3))
    if root_frame is not None:
        root_frame = as_real_array(root_frame, "root_frame", shape=(4, 4))
    world = np.zeros(16 * len(joints))
    _core.forward_kinematics(world, joints.reshape(-1), axes.reshape(-1),
                             np.ascontiguousarray(angles, dtype=np.float64).reshape(-1), skeleton.part_parents,
                             None if root_frame is None else np.ascontiguousarray(root_frame, np.float64).reshape(-1))
    return world.reshape(-1, 4, 4)


@checked(skeleton=BoneSkeleton, moved_part=count(-1, 2**31 - 1))
def collision_candidates(skeleton, moved_part: int = -1) -> np.ndarray:
    """The part pairs (N, 2) a motion can make collide (section 4.3's precomputed lists): every pair but a parent
    and its child, or, for a turn of one joint (moved_part), only the pairs across the border of its subtree."""
    parents = skeleton.part_parents
    if moved_part >= len(parents):
        raise SkinkitError(f"moved_part {moved_part}: not -1 or a part in [0, {len(parents)})")
    pairs = np.zeros(max(len(parents) * (len(parents) - 1), 2), np.int32)
    found = _core.collision_candidates(pairs, parents, moved_part)["pair_count"]
    return pairs[:2 * found].reshape(-1, 2).copy()


@dataclass(frozen=True)
class CollisionTest:
    """The colliding pairs, the candidates whose bounding spheres met, and those box-tested, in test order."""
    pairs: list
    sphere_hits: int
    tested: np.ndarray


@checked(skeleton=BoneSkeleton, first_only=FLAG)
def find_collisions(skeleton, world, candidates=None, first_only: bool = False) -> CollisionTest:
    """Collisions among candidate pairs (default: collision_candidates(skeleton)), box-tested by increasing
    sphere weight (l / r)^2, stopping at the first collision when first_only."""
    parts = len(skeleton.part_parents)
    world = as_real_array(world, "world", shape=(parts, 4, 4))
    candidates = collision_candidates(skeleton) if candidates is None else \
        as_index_array(candidates, "candidates", shape=(None, 2))
    if candidates.size and (candidates.min() < 0 or candidates.max() >= parts):
        raise SkinkitError(f"candidates: a part outside [0, {parts})")
    count_ = len(candidates)
    pairs, tested, weights = np.zeros(2 * max(count_, 1), np.int32), np.zeros(max(count_, 1), np.int32), \
        np.zeros(max(count_, 1))
    report = _core.detect_collisions_among(pairs, tested[:count_], weights[:count_], np.ascontiguousarray(world).reshape(-1),
                                           skeleton.boxes.reshape(-1), skeleton.principal_axes.reshape(-1),
                                           np.ascontiguousarray(candidates, np.int32).reshape(-1), first_only)
    found = report["pair_count"]
    return CollisionTest([tuple(pair) for pair in pairs[:2 * found].reshape(-1, 2).tolist()], report["sphere_hits"],
                         candidates[tested[:report["box_tests"]]])


@checked(skeleton=BoneSkeleton)
def collisions(skeleton, world) -> list[tuple[int, int]]:
    """Every colliding pair of a pose (parent-child pairs excepted), sorted."""
    return sorted(find_collisions(skeleton, world).pairs)


@dataclass(frozen=True)
class Motion:
    """Accepted angles (F, P, 3), world frames (F, P, 4, 4), and per frame the parts whose motion was refused for
    a limit or a collision."""
    times: np.ndarray
    angles: np.ndarray
    world: np.ndarray
    refused_limits: list[list[int]]
    refused_collisions: list[list[int]]


def _chain(parents, part) -> list[int]:
    chain = []
    while part >= 0:
        chain.append(part)
        part = int(parents[part])
    return chain


def _changed_pairs(others, moved) -> np.ndarray:
    """The pairs whose relative pose the moved joints change: the union of their precomputed lists."""
    lists = [others[part] for part in np.flatnonzero(moved).tolist()]
    return np.unique(np.concatenate(lists), axis=0) if len(lists) > 1 else lists[0]


@checked(skeleton=BoneSkeleton, clip=Keyframes, check_collisions=FLAG)
def animate(skeleton, clip: Keyframes, times, limits=None, check_collisions: bool = True) -> Motion:
    """Plays the clip at `times`, refusing motions that break limits ((P, 3, 2) degrees) or make parts collide."""
    parts = len(skeleton.part_parents)
    accepted = np.zeros((parts, 3))
    all_angles, all_world, by_limit, by_collision = [], [], [], []
    parents = skeleton.part_parents
    times = as_real_array(times, "times", shape=(None,))
    if limits is not None:
        limits = as_real_array(limits, "limits", shape=(parts, 3, 2))
    others = [collision_candidates(skeleton, part) for part in range(parts)] if check_collisions else []
    for time in times.tolist():
        wanted = clip.angles(time, parts)
        refused = []
        if limits is not None:
            outside = ((wanted < limits[..., 0]) | (wanted > limits[..., 1])).any(axis=1)
            refused = np.flatnonzero(outside).tolist()
            wanted[outside] = accepted[outside]
        world, turned_back = pose(skeleton, wanted), set()
        for _ in range(parts):
            moved = ~np.isclose(wanted, accepted).all(axis=1)
            pairs = find_collisions(skeleton, world, _changed_pairs(others, moved)).pairs \
                if check_collisions and moved.any() else []
            if not pairs:
                break
            for a, b in pairs:
                path = set(_chain(parents, a)) ^ set(_chain(parents, b))  # the joints between the two parts
                for joint in path:
                    if moved[joint]:
                        wanted[joint] = accepted[joint]
                        turned_back.add(joint)
            world = pose(skeleton, wanted)
        accepted = wanted
        all_angles.append(wanted.copy())
        all_world.append(world)
        by_limit.append(refused)
        by_collision.append(sorted(turned_back))
    return Motion(np.asarray(times, dtype=np.float64), np.array(all_angles), np.array(all_world), by_limit,
                  by_collision)
