"""skinkit's dual-quaternion skinning against Blender's Armature modifier with Preserve Volume, on the samples in
random rigid poses."""
import bpy
import numpy as np
import pytest
from tests.blender.test_skinning import random_pose
from tests.conftest import SAMPLE_NAMES

from skinkit import _core
from skinkit.blender import skinning
from skinkit.blender.frames import evaluated_positions
from skinkit.blender.rig import (bind_matrix, bone_names, deform_weights, pose_matrices, rest_positions, rig_of,
                                 skeleton_of)
from skinkit.model import skinning_matrices

TOLERANCE = 1e-5  # of the bounding-box diagonal


def rigid_dual_quaternions(matrices):
    """Dual quaternions of the skinning matrices, re-orthonormalised (Blender's matrices are float32)."""
    matrices = matrices.copy()
    u, _, vt = np.linalg.svd(matrices[:, :3, :3])
    matrices[:, :3, :3] = u @ vt
    result = np.empty((len(matrices), 8))
    _core.dq_from_rigid(result, np.ascontiguousarray(matrices))
    return result


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_dqs_matches_preserve_volume_in_random_rigid_poses(open_sample, name):
    mesh_object = open_sample(name)
    rig = rig_of(mesh_object)
    rig.modifier.use_deform_preserve_volume = True
    armature = rig.armature_object
    armature.animation_data_clear()
    weights = deform_weights(rig)
    rest = rest_positions(mesh_object)
    diagonal = skinning.bounding_box_diagonal(rest)
    rng = np.random.default_rng(7)
    worst, moved = 0.0, 0.0
    for _ in range(20):
        random_pose(armature, rng, max_angle=1.5, scale_spread=0)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        bind = bind_matrix(rig, depsgraph)
        skeleton = skeleton_of(rig, bind)
        poses = pose_matrices(armature, depsgraph, bone_names(armature), bind)
        dual_quaternions = rigid_dual_quaternions(skinning_matrices(skeleton, poses))
        ours = np.empty_like(rest)
        _core.dqs_evaluate(ours, rest, 1.0, weights.offsets, weights.bones, weights.weights, dual_quaternions, 0)
        reference = evaluated_positions(mesh_object, depsgraph)
        worst = max(worst, float(np.linalg.norm(ours - reference, axis=1).max()) / diagonal)
        moved = max(moved, float(np.linalg.norm(reference - rest, axis=1).max()) / diagonal)
    assert moved > 0.05  # the poses are far from rest
    assert worst < TOLERANCE
