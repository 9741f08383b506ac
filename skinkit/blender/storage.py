"""The animation-space model stored on a Blender mesh (layout version 2; see docs/data-model.md).

Per vertex, K slots k = 0..K-1 of point-domain attributes (they follow the mesh through edits and are
saved in the .blend):
    skinkit_as_bone_k  INT           bone index into the model's bone list, -1 for an empty slot
    skinkit_as_p_k     FLOAT_VECTOR  x, y, z of p_j in bone j's rest frame
    skinkit_as_w_k     FLOAT         the homogeneous weight of p_j
and one ID property on the mesh data, "skinkit_model":
    layout_version (int), slots (int), bones (bone names; "" is the root), armature (object name),
    bind (16 floats, row-major B = armature_world^-1 @ mesh_world at conversion), revision (int,
    +1 on every write), influences_mean and influences_max (for the UI, so it need not read the slots),
    and (since version 2) signature: what the model was built from (rig.model_signature: vertex count,
    topology, rest positions, bone names and deform flags, rest pose, weights), so that Compare, the bakes and
    Live Preview can refuse a model that no longer matches its mesh and rig.
Version 1 (no signature) is still read; its provenance is unknown, which the checks say.
"""
from __future__ import annotations

import numpy as np

from ..model import AnimationSpaceModel, SkinkitError
from .rig import edit_mode_message

PROPERTY = "skinkit_model"
LAYOUT_VERSION = 2
#: Layout versions this skinkit reads (1 lacks the signature).
READABLE_VERSIONS = (1, 2)
BONE_ATTRIBUTE = "skinkit_as_bone_{}"
POSITION_ATTRIBUTE = "skinkit_as_p_{}"
WEIGHT_ATTRIBUTE = "skinkit_as_w_{}"
SLOT_ATTRIBUTES = ((BONE_ATTRIBUTE, "INT", "value", 1), (POSITION_ATTRIBUTE, "FLOAT_VECTOR", "vector", 3),
                   (WEIGHT_ATTRIBUTE, "FLOAT", "value", 1))


class StoredModel:
    """A model read back from a mesh: the sparse model plus the metadata it was bound with."""

    def __init__(self, model: AnimationSpaceModel, bone_names: list[str], armature_name: str, bind: np.ndarray,
                 revision: int, signature: dict | None = None):
        self.model = model
        self.signature = signature
        self.bone_names = bone_names
        self.armature_name = armature_name
        self.bind = bind
        self.revision = revision


def has_model(mesh) -> bool:
    """True when the mesh carries a model of any layout version (it may still be unreadable)."""
    return PROPERTY in mesh


def model_summary(mesh) -> dict | None:
    """Cheap facts for the UI, without reading the per-vertex data; None when there is no model."""
    if not has_model(mesh):
        return None
    meta = mesh[PROPERTY]
    return {"layout_version": int(meta.get("layout_version", 0)), "slots": int(meta.get("slots", 0)),
            "bones": len(meta.get("bones", [])) - 1, "armature": str(meta.get("armature", "")),
            "influences_mean": float(meta.get("influences_mean", 0.0)),
            "influences_max": int(meta.get("influences_max", 0))}


def write_model(mesh, model: AnimationSpaceModel, bone_names: list[str], armature_name: str,
                bind: np.ndarray, signature: dict | None = None) -> None:
    """Replaces any stored model by `model`, with the signature of what it was built from
    (rig.model_signature). All data are prepared first, so a failure leaves the mesh as it was."""
    if model.vertex_count != len(mesh.vertices):
        raise SkinkitError(f"mesh '{mesh.name}' has {len(mesh.vertices)} vertices, the model {model.vertex_count}")
    slots = slot_arrays(model)
    revision = int(mesh[PROPERTY].get("revision", 0)) + 1 if has_model(mesh) else 1
    remove_model(mesh)
    for k, (bones, positions, weights) in enumerate(slots):
        for (template, data_type, field, _), values in zip(SLOT_ATTRIBUTES, (bones, positions, weights)):
            attribute = mesh.attributes.new(template.format(k), data_type, "POINT")
            attribute.data.foreach_set(field, values.reshape(-1))
    mesh[PROPERTY] = {"layout_version": LAYOUT_VERSION, "slots": len(slots), "bones": list(bone_names),
                      "armature": armature_name, "bind": [float(x) for x in bind.reshape(-1)], "revision": revision,
                      "influences_mean": float(model.counts().mean()) if model.vertex_count else 0.0,
                      "influences_max": len(slots)}
    if signature is not None:
        mesh[PROPERTY]["signature"] = signature
    mesh.update()


def slot_arrays(model: AnimationSpaceModel) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The model as K padded slots: (bone int32 (V,), xyz float32 (V, 3), weight float32 (V,)) per slot."""
    counts = model.counts()
    slot_count = int(counts.max()) if model.vertex_count else 0
    vertex = np.repeat(np.arange(model.vertex_count), counts)
    slot = np.arange(model.influence_count) - np.repeat(model.offsets[:-1], counts)
    slots = []
    for k in range(slot_count):
        here = slot == k
        bones = np.full(model.vertex_count, -1, np.int32)
        coordinates = np.zeros((model.vertex_count, 4), np.float32)
        bones[vertex[here]] = model.bones[here]
        coordinates[vertex[here]] = model.coordinates[here]
        slots.append((bones, np.ascontiguousarray(coordinates[:, :3]), np.ascontiguousarray(coordinates[:, 3])))
    return slots


def remove_model(mesh) -> None:
    """Deletes the stored model (attributes and metadata), if any."""
    for name in [a.name for a in mesh.attributes if a.name.startswith("skinkit_as_")]:
        mesh.attributes.remove(mesh.attributes[name])
    if PROPERTY in mesh:
        del mesh[PROPERTY]


def read_model(mesh, owner: str) -> StoredModel:
    """The stored model, checked; `owner` (the object's name) is used in error messages."""
    if not has_model(mesh):
        raise SkinkitError(f"'{owner}' has no animation-space model (run Convert to Animation Space first)")
    if mesh.is_editmode:
        raise SkinkitError(edit_mode_message(owner))
    meta = mesh[PROPERTY]
    version = int(meta.get("layout_version", 0))
    if version not in READABLE_VERSIONS:
        raise SkinkitError(f"'{owner}': model layout version {version} is not supported by this skinkit "
                           f"(it reads version {LAYOUT_VERSION})")
    bone_names = [str(n) for n in meta["bones"]]
    vertex_count = len(mesh.vertices)
    columns = []
    for k in range(int(meta["slots"])):
        columns.append([read_attribute(mesh, owner, template.format(k), data_type, field, width, vertex_count)
                        for template, data_type, field, width in SLOT_ATTRIBUTES])
    bones = np.stack([c[0] for c in columns], axis=1) if columns else np.zeros((vertex_count, 0), np.int32)
    used = bones >= 0
    counts = used.sum(axis=1)
    offsets = np.zeros(vertex_count + 1, np.int32)
    np.cumsum(counts, out=offsets[1:])
    coordinates = np.stack([np.column_stack([c[1], c[2]]) for c in columns], axis=1) if columns else \
        np.zeros((vertex_count, 0, 4))
    try:
        model = AnimationSpaceModel.create(offsets, bones[used], coordinates[used], len(bone_names))
    except SkinkitError as error:
        raise SkinkitError(f"'{owner}': stored model is corrupt: {error}") from None
    bind = np.array(meta["bind"], dtype=np.float64).reshape(4, 4)
    signature = meta.get("signature")
    signature = None if signature is None else {key: (value if isinstance(value, (int, str)) else list(value))
                                                 for key, value in signature.to_dict().items()}
    return StoredModel(model, bone_names, str(meta["armature"]), bind, int(meta.get("revision", 0)), signature)


def read_attribute(mesh, owner, name, data_type, field, width, vertex_count) -> np.ndarray:
    attribute = mesh.attributes.get(name)
    if attribute is None or attribute.data_type != data_type or attribute.domain != "POINT":
        raise SkinkitError(f"'{owner}': stored model is missing point attribute '{name}' ({data_type})")
    values = np.empty(vertex_count * width, np.int32 if data_type == "INT" else np.float32)
    attribute.data.foreach_get(field, values)
    return values.reshape(vertex_count, width) if width > 1 else values
