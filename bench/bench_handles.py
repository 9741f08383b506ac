"""Handle-driven deformation (Feng 2010, chapter 2): held-out frames predicted from a few control points alone,
skinkit's kernel CCA beside the thesis' baselines, on the same control points in one run.

    cd /work/main && .venv/bin/python bench/bench_handles.py [--data ../shared/data] [--handles 10] [--bones 16] \
        [--json bench/handles_results.json] [--markdown bench/handles_results.md]

Data (read in place, never copied): the Dem Bones sample's Bone_Anim.abc (every frame; every 4th held out), the
horse gallop (gallop/0001..0048.obj, every 4th held out), the creature walk (the project's blend_samples/
creature.blend, its 48-frame walk deformed by the Armature modifier with Preserve Volume; every 4th held out). A set
whose files are missing is reported as skipped. The control points are suggested from the training frames (skinkit.handles.suggest_handles:
PCA, varimax, two extreme vertices per component); every method below sees only the training frames and, for a
held-out frame, only the control points' positions in it.

Proxy bones: for each clustering (--clusterings: "rigid", decompose's trajectory k-means merged by rigid error and
refined by rigid k-means; "hierarchical", the triangle hierarchy of skinkit.handles.clusters cut at the count, then
the same rigid k-means) and each count of the sweep (--bones, default 16, 32, 48, 64) skinkit.handles.train's proxy
bones (4 influences, the weights refitted for DQS); the clustering and count whose kCCA has the least 4-fold
validation error on the training frames (ties within 2% to fewer bones) are used for the rows below (the held-out
frames never choose).
Methods:
  kCCA (Gaussian): skinkit.handles.train's predictor on those bones (Gaussian kernel; sigma = section 2.7's x a
      scale and kappa = a ridge x the centred kernel's mean eigenvalue, both chosen by the same validation; the
      predicted translations), predict.
  linear-kernel CCA: the same, kernel "linear".
  kCCA + Poisson translations: the same as kCCA with the translations from the Poisson solve (eq. 2.11, beta 1
      relative to edge_count / handle_count).
  PCA blend shapes: mean + k PCA components of the training frames, the weights by least squares from the
      control points (ridge 1e-6); k in {4, 8, 16, 32} (capped by the examples), the best held-out k is reported
      (the baseline at its most favourable).
  direct RBF: Gaussian RBF interpolation (sigma as kCCA's, ridge 1e-6) from the normalised handle vector to all
      vertex positions.
  PCA + RBF: the same RBF onto the coefficients of the best k PCA components.
  Dem Bones-style LBS: the same proxy bones with the decomposition's linear-blend weights, each frame's bone
      transforms solved from the control points alone (affine least squares on the handles, Tikhonov 1e-2 per
      bone towards the training frames' mean transform, then the nearest rotation), linear blend skinning.
Error: rms vertex distance over the held-out frames divided by the largest side of the rest bounding box (the
thesis' measure). ms/frame: wall clock of predicting one frame (one core), mean over the held-out frames.
Timing target: synthetic rigs of 10,000 vertices, 30 and 64 bones, 4 influences, 300 examples, 10 handles, one
thread (C prediction with the Poisson translations + C DQS per frame), in thread CPU time, the median of 9 rounds of
100 frames (the wall clock beside it). --timing-only re-measures this alone and keeps the data sets' rows of --json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

# One OpenBLAS thread: the rig's small LAPACK calls (kernel CCA on tens to hundreds of examples, inside skinkit's
# own threads) ran up to 35x slower with OpenBLAS' threads on this shared 2-core machine (0.60 s vs 0.017 s a call
# at 22 examples, measured). Set before numpy and skinkit load OpenBLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from skinkit import SkinkitError, _core, handles  # noqa: E402
from skinkit.handles.clusters import CLUSTERINGS  # noqa: E402
from skinkit.handles.train import rms_error  # noqa: E402

from common import machine_info, machine_line, parallel_speedup, write_outputs  # noqa: E402

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HOLD_OUT_EVERY = 4
PCA_COMPONENTS = (4, 8, 16, 32)
RIDGE = 1e-6
LBS_TIKHONOV = 1e-2
#: The thesis' face: kCCA 0.0108 vs PCA blend shapes 0.0143, i.e. a ratio of 0.755.
RATIO_TARGET = 0.76
FRAME_MS_TARGET = 1.0
TIMING_ROUNDS = 9
#: Proxy-bone counts swept per data set, with each clustering (issue 14's follow-ups: 16-48, then 64 for the
#: creature, whose floor at 48 was above the target).
BONE_SWEEP = (16, 32, 48, 64)


def load_dembones(data: str):
    path = os.path.join(data, "dembones", "Bone_Anim.abc")
    if not os.path.exists(path):
        raise FileNotFoundError(path)
    import bpy  # noqa: F401  (read_sequence needs Blender for an .abc)
    from skinkit.blender.scene import empty_scene
    from skinkit.cli.inputs import read_sequence

    empty_scene()
    frames, triangles, _ = read_sequence(path)
    return frames, triangles, "Bone_Anim.abc, every frame"


def load_horse(data: str):
    folder = os.path.join(data, "horse", "gallop")
    if not os.path.isdir(folder):
        raise FileNotFoundError(folder)
    from skinkit.meshio import read_obj_sequence, sequence_files

    frames, triangles = read_obj_sequence(sequence_files(folder))
    return frames, triangles, "horse/gallop/0001..0048.obj"


def load_creature(data: str):
    """The creature sample's walk (blend_samples/creature.blend, frames 1-48 of its action), deformed by its
    Armature modifier with Preserve Volume: a rigged character's motion, as a bare mesh sequence."""
    path = os.path.join(REPOSITORY, "blend_samples", "creature.blend")
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path} (make samples)")
    import bpy
    from skinkit.blender import rig
    from skinkit.blender.frames import armature_modifier_only, depsgraphs_at, evaluated_positions
    from skinkit.blender.scene import find_skinned_mesh

    bpy.ops.wm.open_mainfile(filepath=path)
    scene = bpy.context.scene
    mesh_object = find_skinned_mesh(scene.objects)
    rig.rig_of(mesh_object).modifier.use_deform_preserve_volume = True
    with armature_modifier_only(mesh_object):
        frames = np.stack([evaluated_positions(mesh_object, depsgraph)
                           for depsgraph in depsgraphs_at(range(scene.frame_start, scene.frame_end + 1))])
    return frames, rig.mesh_of(mesh_object).triangles, "blend_samples/creature.blend, action walk, frames " \
        f"{scene.frame_start}-{scene.frame_end}, Armature modifier with Preserve Volume"


LOADERS = {"dembones": load_dembones, "horse gallop": load_horse, "creature walk": load_creature}


# ---- the baselines ----------------------------------------------------------------------------------------------

def pca_basis(train_frames, k):
    flat = train_frames.reshape(len(train_frames), -1)
    mean = flat.mean(axis=0)
    _, _, vt = np.linalg.svd(flat - mean, full_matrices=False)
    return mean, vt[:k]


def pca_blend(train_frames, handle_vertices, targets, k):
    mean, basis = pca_basis(train_frames, k)
    vertex_count = train_frames.shape[1]
    rows = (np.asarray(handle_vertices)[:, None] * 3 + np.arange(3)).ravel()
    a = basis[:, rows].T
    normal = a.T @ a + RIDGE * np.trace(a.T @ a) / k * np.eye(k)
    weights = np.linalg.solve(normal, a.T @ (targets.reshape(len(targets), -1) - mean[rows]).T).T
    return (mean + weights @ basis).reshape(len(targets), vertex_count, 3)


def rbf(train_inputs, train_outputs, sigma):
    """Gaussian RBF interpolation inputs -> outputs; returns the predictor."""
    def gram(a, b):
        return np.exp(-((a[:, None] - b[None]) ** 2).sum(-1) / (2 * sigma ** 2))
    k = gram(train_inputs, train_inputs)
    coefficients = np.linalg.solve(k + RIDGE * np.eye(len(k)), train_outputs)
    return lambda inputs: gram(inputs, train_inputs) @ coefficients


def normalised(model, vectors):
    return (vectors.reshape(len(vectors), -1) - model.handle_mean) / model.handle_scale


def direct_rbf(model, train_frames, targets):
    predictor = rbf(model.training_handles, train_frames.reshape(len(train_frames), -1), model.parameter)
    return predictor(normalised(model, targets)).reshape(len(targets), -1, 3)


def pca_rbf(model, train_frames, targets, k):
    mean, basis = pca_basis(train_frames, k)
    coefficients = (train_frames.reshape(len(train_frames), -1) - mean) @ basis.T
    predictor = rbf(model.training_handles, coefficients, model.parameter)
    return (mean + predictor(normalised(model, targets)) @ basis).reshape(len(targets), -1, 3)


def lbs_from_handles(model, weights, motions, targets):
    """Dem Bones-style LBS: the model's bones with the decomposition's LBS weights, transforms solved from the
    control points."""
    bone_count = motions.shape[1]
    dense = np.zeros((len(model.rest_positions), bone_count))
    dense[np.repeat(np.arange(len(model.rest_positions)), np.diff(weights.offsets)), weights.bones] = weights.weights
    handle_weights = dense[model.handle_vertices]                      # (H, B)
    rest_h = np.column_stack([model.rest_positions[model.handle_vertices], np.ones(model.handle_count)])
    # Unknowns: the top 3x4 of each bone's affine map, x = (B, 12); handle l: sum_b w_lb A_b (v_l, 1) = c_l.
    design = np.zeros((model.handle_count * 3, bone_count * 12))
    for axis in range(3):
        for b in range(bone_count):
            design[axis::3, b * 12 + axis * 4: b * 12 + axis * 4 + 4] = handle_weights[:, b:b + 1] * rest_h
    prior = motions.mean(axis=0)[:, :3, :].reshape(-1)
    lam = LBS_TIKHONOV * np.trace(design.T @ design) / design.shape[1]
    normal = design.T @ design + lam * np.eye(design.shape[1])
    affine = np.linalg.solve(normal, design.T @ targets.reshape(len(targets), -1).T + lam * prior[:, None]).T
    affine = affine.reshape(len(targets), bone_count, 3, 4)
    u, _, vt = np.linalg.svd(affine[..., :3])
    rotations = u @ vt
    rotations[np.linalg.det(rotations) < 0] *= -1  # never a reflection
    skinned = np.einsum("fbij,vj->fvbi", rotations, model.rest_positions) + affine[..., 3][:, None]
    return np.einsum("fvbi,vb->fvi", skinned, dense)


# ---- one data set ---------------------------------------------------------------------------------------------

def timed(predict, targets):
    started = time.perf_counter()
    result = predict(targets)
    return result, (time.perf_counter() - started) * 1000 / len(targets)


def one_frame_at_a_time(model, targets):
    return np.stack([model.predict(frame, threads=1) for frame in targets])


def train_module():
    return sys.modules["skinkit.handles.train"]  # the module (skinkit.handles.train is the function)


def held_out_bone_fit(proxy, test_frames):
    """Each held-out frame's own best proxy-bone motions (the weights fixed, rigid poses solved on the frame
    itself): what the rig would show with ground-truth bone motions, its floor. As dual quaternions (G, B, 8)."""
    decomposition = proxy.decomposition
    motions = decomposition.solve_poses(test_frames, kind="linear") @ np.linalg.inv(decomposition.skeleton.rest_frames)
    u, _, vt = np.linalg.svd(motions[..., :3, :3])
    motions[..., :3, :3] = u @ vt
    motions[..., 3, :] = (0, 0, 0, 1)
    dual_quaternions = np.empty(motions.shape[:2] + (8,))
    _core.dq_from_rigid(dual_quaternions, np.ascontiguousarray(motions))
    return dual_quaternions


def rotation_error_degrees(predicted, truth) -> float:
    """Mean angle between predicted and true bone rotations (the moving bones, every frame)."""
    real = predicted[..., :4] / np.linalg.norm(predicted[..., :4], axis=-1, keepdims=True)
    cosine = np.abs((real * truth[..., :4]).sum(-1))
    return float(np.degrees(2 * np.arccos(np.clip(cosine, 0, 1)))[:, 1:].mean())


def lbs_skinned(model, weights, dual_quaternions):
    """The model's DQS with other weights (the decomposition's LBS weights): the before of the DQS refit."""
    meshes = np.empty((len(dual_quaternions),) + model.rest_positions.shape)
    for mesh, pose in zip(meshes, dual_quaternions):
        _core.dqs_evaluate(mesh, model.rest_positions, 1.0, weights.offsets, weights.bones, weights.weights,
                           np.ascontiguousarray(pose), 1)
    return meshes


def sweep_row(train_frames, test_frames, handle_vertices, proxy, extent):
    """One bone count: the proxy-bone fit alone (training frames; held-out frames with their own bone motions) with
    the LBS and the DQS-refitted weights, kCCA's held-out error with section 2.7's parameters and with the ones
    chosen by validation on the training frames, and its bone-rotation error."""
    trainer = train_module()
    rest = train_frames[0]
    targets = test_frames[:, handle_vertices]
    models = {validate: trainer.rig_on_proxy_bones(train_frames, rest, handle_vertices, proxy, kernel="gaussian",
                                                   basis_count=trainer.DEFAULT_BASIS_COUNT,
                                                   ridge=trainer.DEFAULT_RIDGE, beta=trainer.DEFAULT_BETA,
                                                   poisson=False, validate=validate, threads=1)
              for validate in (False, True)}
    truth = held_out_bone_fit(proxy, test_frames)
    predicted = models[False].predict_bones(targets)
    signs = np.where((truth[..., :4] * predicted[..., :4]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    truth *= signs
    model = models[False]
    lbs = proxy.decomposition.linear_blend
    return {"bones": int(proxy.motions.shape[1] - 1),
            "training_fit_lbs_weights": proxy.lbs_weights_fit_rms / extent,
            "training_fit_dqs_weights": model.report["proxy_bone_fit_rms"],
            "held_out_fit_lbs_weights": rms_error(lbs_skinned(model, lbs, truth), test_frames, extent),
            "held_out_fit_dqs_weights": rms_error(model.skin(truth), test_frames, extent),
            "held_out_kcca": rms_error(model.skin(predicted), test_frames, extent),
            "held_out_kcca_validated": rms_error(models[True].predict(targets), test_frames, extent),
            "validation": models[True].report["validation"],
            "rotation_error_degrees": rotation_error_degrees(predicted, truth),
            "training_kcca": model.report["training_rms"]}


def run_dataset(name, frames, triangles, source, handle_count, sweep, clusterings, experiments=False):
    held_out = np.arange(len(frames)) % HOLD_OUT_EVERY == HOLD_OUT_EVERY - 1
    train_frames, test_frames = frames[~held_out], frames[held_out]
    extent = float(np.ptp(train_frames[0], axis=0).max())
    handle_vertices = handles.suggest_handles(train_frames, handle_count)
    targets = test_frames[:, handle_vertices]
    trainer = train_module()
    started = time.perf_counter()
    hierarchy = trainer.triangle_hierarchy(train_frames[0], train_frames, triangles)
    hierarchy_seconds = time.perf_counter() - started
    proxies, sweep_rows = {}, []
    for clustering in clusterings:
        for bones in sweep:
            started = time.perf_counter()
            proxies[clustering, bones] = trainer.proxy_bones(train_frames, triangles, train_frames[0], bones, 4, True,
                                                             0, 0, clustering=clustering, hierarchy=hierarchy)
            seconds = time.perf_counter() - started
            sweep_rows.append({**sweep_row(train_frames, test_frames, handle_vertices, proxies[clustering, bones],
                                           extent), "clustering": clustering, "proxy_seconds": seconds})
            print(f"  {name}, {clustering}, {bones} bones: {sweep_rows[-1]}", file=sys.stderr, flush=True)
    # The clustering and bone count by validation on the training frames only (never the held-out frames), ties
    # within train.BONE_COUNT_TIE going to fewer bones (as train(bone_counts=...) chooses).
    least = min(row["validation"]["rms"] for row in sweep_rows)
    tied = [row for row in sweep_rows if row["validation"]["rms"] <= (1 + trainer.BONE_COUNT_TIE) * least]
    chosen_row = min(tied, key=lambda row: (row["bones"], row["validation"]["rms"]))
    chosen, chosen_clustering = chosen_row["bones"], chosen_row["clustering"]
    proxy = proxies[chosen_clustering, chosen]
    rows = {}
    models = {}
    for label, kernel, poisson in (("kCCA (Gaussian)", "gaussian", False), ("linear-kernel CCA", "linear", False),
                                   ("kCCA (Gaussian) + Poisson translations", "gaussian", True)):
        started = time.perf_counter()
        try:
            model = trainer.rig_on_proxy_bones(train_frames, train_frames[0], handle_vertices, proxy, kernel=kernel,
                                               basis_count=trainer.DEFAULT_BASIS_COUNT, ridge=trainer.DEFAULT_RIDGE,
                                               beta=trainer.DEFAULT_BETA, poisson=poisson, validate=True, threads=0)
        except SkinkitError as refused:  # e.g. the Poisson solve on a mesh with a part that holds no handle
            rows[label] = {"error": str(refused)}
            continue
        seconds = time.perf_counter() - started
        predicted, ms = timed(lambda t: one_frame_at_a_time(model, t), targets)
        rows[label] = {"rms": rms_error(predicted, test_frames, extent), "ms_per_frame": ms, "train_seconds": seconds,
                       "training_rms": model.report["training_rms"],
                       "proxy_bone_fit_rms": model.report["proxy_bone_fit_rms"]}
        models[label] = model
    model = models["kCCA (Gaussian)"]
    components = [k for k in PCA_COMPONENTS if k < len(train_frames)]
    pca = {k: timed(lambda t: pca_blend(train_frames, handle_vertices, t, k), targets) for k in components}
    best_k = min(pca, key=lambda k: rms_error(pca[k][0], test_frames, extent))
    for k, (predicted, ms) in pca.items():
        rows[f"PCA blend shapes, k = {k}"] = {"rms": rms_error(predicted, test_frames, extent), "ms_per_frame": ms}
    predicted, ms = timed(lambda t: direct_rbf(model, train_frames, t), targets)
    rows["direct RBF"] = {"rms": rms_error(predicted, test_frames, extent), "ms_per_frame": ms}
    predicted, ms = timed(lambda t: pca_rbf(model, train_frames, t, best_k), targets)
    rows[f"PCA + RBF, k = {best_k}"] = {"rms": rms_error(predicted, test_frames, extent), "ms_per_frame": ms}
    decomposition = proxy.decomposition
    motions = decomposition.training_poses @ np.linalg.inv(decomposition.skeleton.rest_frames)
    predicted, ms = timed(lambda t: lbs_from_handles(model, decomposition.linear_blend, motions, t), targets)
    rows["Dem Bones-style LBS from the handles"] = {"rms": rms_error(predicted, test_frames, extent),
                                                    "ms_per_frame": ms}
    pca_best = rows[f"PCA blend shapes, k = {best_k}"]["rms"]
    return {"name": name, "source": source, "vertices": int(frames.shape[1]), "frames": int(len(frames)),
            "training_frames": int((~held_out).sum()), "held_out_frames": int(held_out.sum()),
            "handle_vertices": handle_vertices.tolist(), "bones": chosen, "clustering": chosen_clustering,
            "hierarchy_seconds": hierarchy_seconds, "best_pca_components": best_k,
            "rows": rows, "sweep": sweep_rows, "validation": model.report["validation"],
            "ratio_to_pca": rows["kCCA (Gaussian)"]["rms"] / pca_best,
            "linear_ratio_to_pca": rows["linear-kernel CCA"]["rms"] / pca_best,
            **({"experiments": predictor_experiments(model, proxy, train_frames, test_frames, handle_vertices, extent,
                                                     pca_best)} if experiments else {})}


# ---- predictor experiments (--experiments) ----------------------------------------------------------------------
# Two ways past the Gaussian kCCA's rotation error, each with its settings chosen by the same 4-fold validation on the
# training frames (train.validation_folds: the distinct poses interleaved), the held-out frames never choosing; the
# held-out error of every setting is reported beside the validation error, to show whether validation points the
# right way.

#: Matérn 3/2 length scales tried, relative to section 2.7's sigma (wider than KERNEL_SCALES: its optimum is longer).
MATERN_SCALES = (1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0)
#: The handle fit's observation variance per coordinate, relative to the squared bounding-box extent.
HANDLE_FIT_NOISES = (1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3)
#: Weight of the training poses' own covariance beside the validation residuals' in the handle fit's prior.
HANDLE_FIT_POSE_MIX = (0.0, 0.3, 1.0)
HANDLE_FIT_ITERATIONS = 3
FINITE_DIFFERENCE = 1e-6


def matern32(a, b, length):
    distance = np.sqrt(np.maximum(((a[:, None] - b[None]) ** 2).sum(-1), 0)) * np.sqrt(3) / length
    return (1 + distance) * np.exp(-distance)


def normalised_dqs(dqs):
    """Unit real parts, dual parts orthogonal to them (what sk_handle_predict's normalisation gives)."""
    dqs = dqs / np.linalg.norm(dqs[..., :4], axis=-1, keepdims=True)
    dqs[..., 4:] -= (dqs[..., :4] * dqs[..., 4:]).sum(-1, keepdims=True) * dqs[..., :4]
    return dqs


def kcca_with_kernel(kernel, fitting_inputs, fitting_dqs, query_inputs, ridge):
    """train.fitted_predictor's kernel CCA on any kernel function (kernel(a, b) -> Gram matrix), predicting the
    bone dual quaternions of query_inputs."""
    gram = kernel(fitting_inputs, fitting_inputs)
    centred = gram - gram.mean(axis=0) - gram.mean(axis=1)[:, None] + gram.mean()
    kappa = ridge * max(float(np.trace(centred)) / len(gram), 1e-300)
    examples, bone_count = fitting_dqs.shape[:2]
    mapping, offset = np.empty((bone_count * 8, examples)), np.empty(bone_count * 8)
    _core.kernel_cca(mapping, offset, np.empty((bone_count, 8)), np.ascontiguousarray(gram),
                     np.ascontiguousarray(fitting_dqs), bone_count, 8, 8, kappa, 1)
    return normalised_dqs((kernel(query_inputs, fitting_inputs) @ mapping.T + offset).reshape(len(query_inputs),
                                                                                               bone_count, 8))


def validation_error(model, train_frames, folds, predict_fold) -> float:
    """rms over the training frames, each fold predicted by predict_fold(fold) (bone dual quaternions)."""
    total = 0.0
    for fold in np.unique(folds):
        total += float(((model.skin(predict_fold(fold)) - train_frames[folds == fold]) ** 2).sum())
    return float(np.sqrt(total / train_frames.shape[0] / train_frames.shape[1]))


def matern_experiment(model, proxy, train_frames, test_frames, handle_vertices, extent):
    inputs, dqs = model.training_handles, proxy.dual_quaternions
    folds = train_module().validation_folds(inputs)
    queries = normalised(model, test_frames[:, handle_vertices])
    sigma = train_module().kernel_parameter("gaussian", inputs)
    settings = []
    for scale in MATERN_SCALES:
        kernel = (lambda a, b, length=scale * sigma: matern32(a, b, length))
        for ridge in train_module().RIDGES:
            validation = validation_error(model, train_frames, folds, lambda fold: kcca_with_kernel(
                kernel, inputs[folds != fold], dqs[folds != fold], inputs[folds == fold], ridge))
            held_out = model.skin(kcca_with_kernel(kernel, inputs, dqs, queries, ridge))
            settings.append({"scale": scale, "ridge": ridge, "validation": validation / extent,
                             "held_out": rms_error(held_out, test_frames, extent)})
    return settings


def handle_skinning(model):
    """skin(dqs) of the handle vertices alone: their rest positions and influences (a sub-CSR of the model's)."""
    rows = [np.arange(model.offsets[v], model.offsets[v + 1]) for v in model.handle_vertices]
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(np.int32)
    bones = np.ascontiguousarray(np.concatenate([model.bones[r] for r in rows]), dtype=np.int32)
    weights = np.concatenate([model.weights[r] for r in rows])
    rest = np.ascontiguousarray(model.rest_positions[model.handle_vertices])
    out = np.empty_like(rest)

    def skin(dqs):
        _core.dqs_evaluate(out, rest, 1.0, offsets, bones, weights, np.ascontiguousarray(dqs), 1)
        return out.ravel().copy()
    return skin, np.unique(bones)


def handle_fit(skin, moving_bones, predicted, handles, prior, noise):
    """The bone dual quaternions nearest the prediction (in the prior's metric, prior = L'L over the flattened
    (B*8) bone coordinates) whose skinned handle vertices meet the given handles up to the observation variance
    noise: Gauss-Newton with a finite-difference Jacobian over the bones that move a handle."""
    columns = (moving_bones[:, None] * 8 + np.arange(8)).ravel()
    start = predicted.ravel()
    current = predicted.copy()
    for _ in range(HANDLE_FIT_ITERATIONS):
        base = skin(current)
        jacobian = np.zeros((base.size, current.size))
        for column in columns:
            moved = current.ravel().copy()
            moved[column] += FINITE_DIFFERENCE
            jacobian[:, column] = (skin(moved.reshape(current.shape)) - base) / FINITE_DIFFERENCE
        offset = current.ravel() - start
        projected = jacobian @ prior.T
        system = projected @ projected.T + noise * np.eye(base.size)
        step = prior.T @ (projected.T @ np.linalg.solve(system, handles.ravel() - base + jacobian @ offset)) - offset
        current = normalised_dqs((current.ravel() + step).reshape(current.shape)[None])[0]
    return current


def handle_fit_experiment(model, proxy, train_frames, test_frames, handle_vertices, extent):
    """The validated Gaussian kCCA's prediction corrected to meet the handles (handle_fit), the prior being its own
    validation residuals' covariance (+ a mix of the training poses' covariance)."""
    trainer = train_module()
    inputs, dqs = model.training_handles, proxy.dual_quaternions
    folds = trainer.validation_folds(inputs)
    weights = proxy.weights
    fold_dqs = np.empty_like(dqs)
    for fold in np.unique(folds):
        fitting = folds != fold
        known = np.ascontiguousarray(inputs[fitting])
        mapping, offset, _, _ = trainer.fitted_predictor(known, dqs[fitting], "gaussian", model.parameter,
                                                         model.degree, 8, model.report["validation"]["ridge"], 1)
        fold_model = handles.HandleModel(model.rest_positions, model.triangles, weights.offsets, weights.bones,
                                         weights.weights, handle_vertices, model.handle_mean, model.handle_scale,
                                         known, "gaussian", model.parameter, model.degree, mapping, offset, None,
                                         None)
        fold_dqs[folds == fold] = fold_model.predict_bones(train_frames[folds == fold][:, handle_vertices])
    fold_dqs *= np.where((fold_dqs[..., :4] * dqs[..., :4]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    residuals = (dqs - normalised_dqs(fold_dqs)).reshape(len(dqs), -1)
    poses = (dqs - dqs.mean(axis=0)).reshape(len(dqs), -1)
    skin, moving_bones = handle_skinning(model)
    predicted = model.predict_bones(test_frames[:, handle_vertices])
    settings = []
    for mix in HANDLE_FIT_POSE_MIX:
        for noise in HANDLE_FIT_NOISES:
            def prior_of(rows):
                return np.vstack([residuals[rows], np.sqrt(mix) * poses[rows]]) / np.sqrt(rows.sum())
            absolute = noise * extent ** 2
            validation = validation_error(model, train_frames, folds, lambda fold: np.stack([
                handle_fit(skin, moving_bones, start, train_frames[index, handle_vertices],
                           prior_of(folds != fold), absolute)
                for index, start in zip(np.flatnonzero(folds == fold), fold_dqs[folds == fold])]))
            corrected = np.stack([handle_fit(skin, moving_bones, start, handle, prior_of(np.ones(len(dqs), bool)),
                                             absolute)
                                  for start, handle in zip(predicted, test_frames[:, handle_vertices])])
            settings.append({"pose_mix": mix, "noise": noise, "validation": validation / extent,
                             "held_out": rms_error(model.skin(corrected), test_frames, extent)})
    return settings


def predictor_experiments(model, proxy, train_frames, test_frames, handle_vertices, extent, pca_best):
    result = {}
    for name, experiment in (("matern32", matern_experiment), ("handle_fit", handle_fit_experiment)):
        started = time.thread_time()
        settings = experiment(model, proxy, train_frames, test_frames, handle_vertices, extent)
        chosen = min(settings, key=lambda setting: setting["validation"])
        result[name] = {"settings": settings, "chosen": chosen, "ratio_to_pca": chosen["held_out"] / pca_best,
                        "best_held_out_ratio": min(s["held_out"] for s in settings) / pca_best,
                        "cpu_seconds": time.thread_time() - started}
        print(f"  experiment {name}: chosen {chosen}, ratio {result[name]['ratio_to_pca']:.3f}", file=sys.stderr,
              flush=True)
    return result


# ---- the 10k-vertex timing -------------------------------------------------------------------------------------

#: The timed rigs: 10,000 vertices, 4 influences, 300 examples, 10 handles; 30 bones (issue 14's size) and 64 (the
#: Dem Bones rig's count, the largest the validation picks).
TIMED_BONES = (30, 64)


def cpu_and_wall_ms(step, targets) -> dict:
    """Per-frame cost of step over TIMING_ROUNDS rounds of the frames in targets: this thread's CPU time (what the
    frame costs, whatever else the shared machine runs) and the wall clock (which waits for the CPU when other
    processes hold it), each as the best and the median round."""
    cpu, wall = [], []
    for _ in range(TIMING_ROUNDS):
        cpu_started, wall_started = time.thread_time(), time.perf_counter()
        for frame in targets:
            step(frame)
        cpu.append((time.thread_time() - cpu_started) * 1000 / len(targets))
        wall.append((time.perf_counter() - wall_started) * 1000 / len(targets))
    return {"cpu_ms": float(np.median(cpu)), "cpu_ms_best": min(cpu), "wall_ms": float(np.median(wall)),
            "wall_ms_best": min(wall)}


def synthetic_timing(vertices=10_000, bones=30, examples=300, handle_count=10, frames=100, seed=0):
    """Predict + skin on one thread for a rig of the target's size (random but valid arrays: the cost does not
    depend on the values), with the Poisson translations (the dearer prediction)."""
    rng = np.random.default_rng(seed)
    rest = rng.normal(size=(vertices, 3))
    offsets = np.arange(0, 4 * vertices + 1, 4, dtype=np.int32)
    influence_bones = np.ascontiguousarray(np.stack([rng.choice(bones, 4, replace=False) for _ in range(vertices)])
                                           .ravel().astype(np.int32))
    weights = rng.dirichlet(np.ones(4), size=vertices).ravel()
    training = rng.normal(size=(examples, 3 * handle_count))
    mapping = rng.normal(size=(bones * 8, examples)) * 1e-3
    offset = np.tile([1.0, 0, 0, 0, 0, 0, 0, 0], bones)
    model = handles.HandleModel(rest, np.zeros((0, 3), np.int32), offsets, influence_bones, weights,
                                np.arange(handle_count, dtype=np.int32), np.zeros(3 * handle_count), 1.0, training,
                                "gaussian", 1.0, 1, mapping, offset, rng.normal(size=(bones, bones, 3)),
                                rng.normal(size=(bones, handle_count)))
    targets = rng.normal(size=(frames, handle_count, 3))
    dqs, kernel_values = np.empty((bones, 8)), np.empty(examples)
    skinned = np.empty((vertices, 3))
    model.predict(targets[0])  # warm
    predict = cpu_and_wall_ms(lambda frame: _core.handle_predict(
        dqs, kernel_values, frame, model.handle_mean, 1.0, training, 0, 1.0, 1, mapping, offset,
        model.translation_rotations, model.translation_handles), targets)
    skin = cpu_and_wall_ms(lambda frame: _core.dqs_evaluate(skinned, rest, 1.0, offsets, influence_bones, weights,
                                                            dqs, 1), targets)
    python = cpu_and_wall_ms(lambda frame: model.predict(frame, threads=1), targets)
    return {"vertices": vertices, "bones": bones, "examples": examples, "handles": handle_count,
            "predict": predict, "skin": skin, "frame_cpu_ms": predict["cpu_ms"] + skin["cpu_ms"],
            "frame_wall_ms": predict["wall_ms"] + skin["wall_ms"], "through_python_api": python,
            "rounds": TIMING_ROUNDS, "frames_per_round": frames, "load_average_before": os.getloadavg()}


def timings() -> list[dict]:
    rows = []
    for bones in TIMED_BONES:
        rows.append(synthetic_timing(bones=bones))
        rows[-1]["load_average_after"] = os.getloadavg()
    return rows


# ---- report --------------------------------------------------------------------------------------------------

def experiment_lines(experiments) -> list[str]:
    matern, fit = experiments["matern32"], experiments["handle_fit"]
    lines = [f"Predictor experiments (--experiments; settings chosen by the 4-fold validation on the training frames): "
             f"Matérn 3/2 kernel (scale {matern['chosen']['scale']} x sigma, ridge {matern['chosen']['ridge']:g}) "
             f"**{matern['ratio_to_pca']:.3f}** x PCA (the best held-out of its {len(matern['settings'])} settings: "
             f"{matern['best_held_out_ratio']:.3f}); kCCA + handle fit (pose mix {fit['chosen']['pose_mix']}, noise "
             f"{fit['chosen']['noise']:g}) **{fit['ratio_to_pca']:.3f}** x PCA (best held-out of any setting: "
             f"{fit['best_held_out_ratio']:.3f}; {fit['cpu_seconds']:.0f} s CPU). Handle fit settings:", "",
             "| pose mix | noise | validation rms | held-out rms |", "|---:|---:|---:|---:|"]
    for setting in fit["settings"]:
        lines.append(f"| {setting['pose_mix']} | {setting['noise']:g} | {setting['validation']:.5f} | "
                     f"{setting['held_out']:.5f} |")
    return lines + [""]


def markdown_report(results) -> str:
    lines = ["# Handle-driven deformation: kernel CCA vs the thesis' baselines", "",
             machine_line(results["machine"]) + ")", "", "`bench/bench_handles.py`", "",
             __doc__.split("\n\n", 2)[2].strip(), ""]
    for skipped in results["skipped"]:
        lines += [f"Skipped: {skipped}", ""]
    for data in results["datasets"]:
        lines += [f"## {data['name']}", "",
                  f"{data['source']}: {data['vertices']} vertices, {data['frames']} frames, "
                  f"{data['training_frames']} train / {data['held_out_frames']} held out; {len(data['handle_vertices'])} "
                  f"control points {data['handle_vertices']}; {data['bones']} proxy bones.", "",
                  "| method | held-out rms | ms / frame | training rms | proxy-bone fit rms | train s |",
                  "|---|---:|---:|---:|---:|---:|"]
        for label, row in data["rows"].items():
            if "error" in row:
                lines.append(f"| {label} | refused: {row['error']} | | | | |")
                continue
            extra = [f"{row[key]:.4g}" if key in row else "" for key in ("training_rms", "proxy_bone_fit_rms",
                                                                         "train_seconds")]
            lines.append(f"| {label} | {row['rms']:.4g} | {row['ms_per_frame']:.3g} | " + " | ".join(extra) + " |")
        pca_best = data["rows"][f"PCA blend shapes, k = {data['best_pca_components']}"]["rms"]
        chosen = data["validation"]
        lines += ["", f"Validation on the training frames chose the {data['clustering']} clustering with "
                      f"{data['bones']} bones, kernel scale "
                      f"{chosen['kernel_scale']} x section 2.7's sigma and ridge {chosen['ridge']:g}.", "",
                  "Bone sweep (weights refitted for DQS unless said; 'fit' = the proxy bones with each frame's own "
                  "best bone motions, the rig's floor; kCCA = predicted from the handles; ratio = held-out kCCA / best "
                  "PCA blend shapes; rot = mean bone-rotation error of the prediction; val = 4-fold validation rms "
                  "on the training frames, which picks the clustering and bone count; the triangle hierarchy took "
                  f"{data['hierarchy_seconds']:.1f} s, once for every count):", "",
                  "| clustering | bones | train fit, LBS w | train fit, DQS w | held-out fit, LBS w | held-out fit, DQS w | "
                  "held-out kCCA | held-out kCCA, validated | ratio (validated) | floor ratio | rot deg | val | "
                  "proxy s |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for row in data["sweep"]:
            lines.append(f"| {row['clustering']} | {row['bones']} | {row['training_fit_lbs_weights']:.4g} | "
                         f"{row['training_fit_dqs_weights']:.4g} | {row['held_out_fit_lbs_weights']:.4g} | "
                         f"{row['held_out_fit_dqs_weights']:.4g} | {row['held_out_kcca']:.4g} | "
                         f"{row['held_out_kcca_validated']:.4g} | {row['held_out_kcca_validated'] / pca_best:.3f} | "
                         f"{row['held_out_fit_dqs_weights'] / pca_best:.3f} | {row['rotation_error_degrees']:.3f} | "
                         f"{row['validation']['rms']:.4g} | {row['proxy_seconds']:.0f} |")
        lines += ["", f"kCCA / best PCA blend shapes: **{data['ratio_to_pca']:.3f}** (target <= {RATIO_TARGET}); "
                      f"linear-kernel CCA / PCA: {data['linear_ratio_to_pca']:.3f}.", ""]
        if "experiments" in data:
            lines += experiment_lines(data["experiments"])
    timing_machine = results.get("timing_machine")
    lines += ["## Time per frame at the target size", ""]
    if timing_machine:
        lines += [f"Measured separately (`{timing_machine['command']}`): " + machine_line(timing_machine) + ").", ""]
    lines += [
              "Synthetic rigs of 10,000 vertices, 4 influences, 300 examples, 10 handles, with the Poisson "
              "translations, one thread. CPU = this thread's CPU time per frame (time.thread_time; what the frame "
              "costs, whatever else the shared machine runs), wall = the clock (it also counts the waits for a CPU "
              f"held by other processes); the median of {TIMING_ROUNDS} rounds, the best beside it.", "",
              "| bones | prediction CPU ms | DQS CPU ms | **frame CPU ms** | frame wall ms | HandleModel.predict CPU "
              "ms | load average before / after |", "|---:|---:|---:|---:|---:|---:|---|"]
    for timing in results["timing"]:
        load = "/".join(f"{value:.1f}" for value in timing["load_average_before"]) + " / " + \
            "/".join(f"{value:.1f}" for value in timing["load_average_after"])
        lines.append(f"| {timing['bones']} | {timing['predict']['cpu_ms']:.3f} "
                     f"({timing['predict']['cpu_ms_best']:.3f}) | "
                     f"{timing['skin']['cpu_ms']:.3f} ({timing['skin']['cpu_ms_best']:.3f}) | "
                     f"**{timing['frame_cpu_ms']:.3f}** | {timing['frame_wall_ms']:.3f} | "
                     f"{timing['through_python_api']['cpu_ms']:.3f} | {load} |")
    lines += ["", "## Targets", "", "| target | met | numbers |", "|---|---|---|"]
    for data in results["datasets"]:
        met = "yes" if data["ratio_to_pca"] <= RATIO_TARGET else "NO"
        lines.append(f"| {data['name']}: kCCA <= {RATIO_TARGET} x PCA | {met} | ratio {data['ratio_to_pca']:.3f} |")
    for timing in results["timing"]:
        met = "yes" if timing["frame_cpu_ms"] < FRAME_MS_TARGET else "NO"
        lines.append(f"| < {FRAME_MS_TARGET} ms CPU / frame at 10k vertices, {timing['bones']} bones, 300 examples, "
                     f"one core | {met} | {timing['frame_cpu_ms']:.3f} ms |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
    parser.add_argument("--handles", type=int, default=10)
    parser.add_argument("--bones", default=",".join(map(str, BONE_SWEEP)),
                        help="the proxy-bone counts swept; the kCCA rows use the one validation on the training "
                             "frames picks")
    parser.add_argument("--clusterings", default=",".join(CLUSTERINGS),
                        help="the proxy-bone clusterings swept, of: " + ", ".join(CLUSTERINGS))
    parser.add_argument("--datasets", default=",".join(LOADERS), help="comma-separated, of: " + ", ".join(LOADERS))
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    parser.add_argument("--experiments", action="store_true",
                        help="also the predictor experiments (Matern 3/2 kernel, the handle fit), chosen by validation")
    parser.add_argument("--timing-only", action="store_true",
                        help="re-measure the time per frame alone, keeping the data sets' rows of --json")
    arguments = parser.parse_args()
    if arguments.timing_only:
        return timing_only(arguments)
    speedup_before = parallel_speedup()
    results = {"datasets": [], "skipped": []}
    for name, loader in LOADERS.items():
        if name not in arguments.datasets.split(","):
            continue
        try:
            frames, triangles, source = loader(arguments.data)
        except (FileNotFoundError, ImportError) as missing:
            results["skipped"].append(f"{name}: {missing}")
            print(f"skipping {name}: {missing}", file=sys.stderr)
            continue
        print(f"{name}: {frames.shape}", file=sys.stderr)
        results["datasets"].append(run_dataset(name, frames, triangles, source, arguments.handles,
                                               [int(b) for b in arguments.bones.split(",")],
                                               arguments.clusterings.split(","), arguments.experiments))
    results["timing"] = timings()
    results["machine"] = {**machine_info(), "parallel_speedup_before": speedup_before,
                          "parallel_speedup_after": parallel_speedup()}
    write_outputs(results, arguments.json, arguments.markdown, markdown_report)
    print(markdown_report(results))


def timing_only(arguments) -> None:
    """The timing section re-measured into the results of an earlier full run (--json), its machine record
    (timing_machine) beside the data sets' own."""
    results = {"datasets": [], "skipped": ["data sets: not run (--timing-only)"]}
    if arguments.json and os.path.exists(arguments.json):
        with open(arguments.json) as stream:
            results = json.load(stream)
    speedup_before = parallel_speedup()
    results["timing"] = timings()
    results["timing_machine"] = {**machine_info(), "parallel_speedup_before": speedup_before,
                                 "parallel_speedup_after": parallel_speedup()}
    results.setdefault("machine", results["timing_machine"])
    write_outputs(results, arguments.json, arguments.markdown, markdown_report)
    print(markdown_report(results))


if __name__ == "__main__":
    main()
