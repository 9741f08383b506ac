"""A trained handle rig: what prediction needs, saved to and loaded from .npz (versioned)."""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from .. import _core
from .._checks import PATH, THREADS, SkinkitError, as_real_array, checked

#: The kernels of section 2.7, in the C core's numbering (sk_kernel).
KERNELS = ("gaussian", "polynomial", "linear")
#: Bumped when the stored arrays change meaning; load() refuses other versions.
FORMAT_VERSION = 1


@dataclass(eq=False)
class HandleModel:
    """Proxy-bone skinned mesh driven by handles. Bone arrays are over the bone_count proxy bones (bone 0 the
    static root); dual quaternions are (real w x y z, dual w x y z) of the skinning motion rest -> pose."""

    rest_positions: np.ndarray      # (V, 3)
    triangles: np.ndarray           # (T, 3) int32
    offsets: np.ndarray             # (V + 1,) int32: the weights' CSR pattern
    bones: np.ndarray               # (I,) int32
    weights: np.ndarray             # (I,)
    handle_vertices: np.ndarray     # (H,) int32
    handle_mean: np.ndarray         # (H * 3,)
    handle_scale: float
    training_handles: np.ndarray    # (E, H * 3), normalised
    kernel: str
    parameter: float
    degree: int
    mapping: np.ndarray             # (B * 8, E)
    mapping_offset: np.ndarray      # (B * 8,)
    translation_rotations: np.ndarray | None  # (B, B, 3) or None: the mapping's own translations
    translation_handles: np.ndarray | None    # (B, H)
    report: dict = field(default_factory=dict)

    @property
    def bone_count(self) -> int:
        return len(self.mapping_offset) // 8

    @property
    def handle_count(self) -> int:
        return len(self.handle_vertices)

    def handle_positions_of(self, frames) -> np.ndarray:
        """The handles' positions (G, H, 3) in frames (G, V, 3) of the training mesh."""
        frames = as_real_array(frames, "frames", shape=(None, len(self.rest_positions), 3))
        return np.ascontiguousarray(frames[:, self.handle_vertices])

    def predict_bones(self, handle_positions) -> np.ndarray:
        """Bone dual quaternions (G, B, 8) for handle positions (G, H, 3) or one frame (H, 3) (then (B, 8))."""
        positions, single = self._checked_handles(handle_positions)
        result = np.empty((len(positions), self.bone_count, 8))
        scratch = np.empty(len(self.training_handles))
        for frame, handles in enumerate(positions):
            _core.handle_predict(result[frame], scratch, handles, self.handle_mean, self.handle_scale,
                                 self.training_handles, KERNELS.index(self.kernel), self.parameter, self.degree,
                                 self.mapping, self.mapping_offset, self.translation_rotations,
                                 self.translation_handles)
        return result[0] if single else result

    @checked(threads=THREADS)
    def skin(self, dual_quaternions, threads: int = 1) -> np.ndarray:
        """Dual-quaternion skinning of the rest mesh with bone dual quaternions (B, 8) or (G, B, 8)."""
        dqs = as_real_array(dual_quaternions, "dual_quaternions")
        single = dqs.ndim == 2
        if dqs.ndim not in (2, 3) or dqs.shape[-2:] != (self.bone_count, 8):
            raise SkinkitError(f"dual_quaternions: expected shape ({self.bone_count}, 8) or (frames, "
                               f"{self.bone_count}, 8), got {dqs.shape}")
        dqs = dqs.reshape(-1, self.bone_count, 8)
        meshes = np.empty((len(dqs), len(self.rest_positions), 3))
        for frame, pose in enumerate(dqs):
            _core.dqs_evaluate(meshes[frame], self.rest_positions, 1.0, self.offsets, self.bones, self.weights,
                               np.ascontiguousarray(pose), threads)
        return meshes[0] if single else meshes

    @checked(threads=THREADS)
    def predict(self, handle_positions, threads: int = 1) -> np.ndarray:
        """The deformed mesh (V, 3) for one frame of handle positions (H, 3), or (G, V, 3) for (G, H, 3)."""
        return self.skin(self.predict_bones(handle_positions), threads)

    def _checked_handles(self, handle_positions):
        positions = as_real_array(handle_positions, "handle_positions")
        single = positions.ndim == 2
        if positions.shape[-2:] != (self.handle_count, 3) or positions.ndim not in (2, 3):
            raise SkinkitError(f"handle_positions: expected shape ({self.handle_count}, 3) or "
                               f"(frames, {self.handle_count}, 3), got {positions.shape}")
        return positions.reshape(-1, self.handle_count, 3), single

    # ---- storage --------------------------------------------------------------------------------------------

    def arrays(self) -> dict:
        """The model as named arrays (what save() writes and the .blend stores), with its format version."""
        stored = {"format_version": np.array(FORMAT_VERSION)}
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "report":
                continue
            if value is None:
                continue
            stored[item.name] = np.asarray(value)
        return stored

    @checked(path=PATH)
    def save(self, path) -> None:
        try:
            with open(path, "wb") as stream:
                np.savez_compressed(stream, **self.arrays())
        except OSError as error:
            raise SkinkitError(f"path: cannot write {path!r} ({error.strerror or error})") from None

    @classmethod
    def from_arrays(cls, stored) -> "HandleModel":
        if not isinstance(stored, dict):
            raise SkinkitError(f"stored: expected a dict of named arrays (HandleModel.arrays), got "
                               f"{type(stored).__name__}")
        version = int(stored["format_version"]) if "format_version" in stored else None
        if version != FORMAT_VERSION:
            raise SkinkitError(f"handle model: format version {version}, this skinkit reads {FORMAT_VERSION}")
        values = {}
        for item in fields(cls):
            if item.name == "report":
                continue
            if item.name not in stored:
                if item.name.startswith("translation_"):
                    values[item.name] = None
                    continue
                raise SkinkitError(f"handle model: '{item.name}' is missing")
            values[item.name] = np.asarray(stored[item.name])
        for name in ("handle_scale", "parameter"):
            values[name] = float(values[name])
        values["degree"] = int(values["degree"])
        values["kernel"] = str(values["kernel"])
        for name in ("triangles", "offsets", "bones", "handle_vertices"):
            values[name] = np.ascontiguousarray(values[name], np.int32)
        return cls(**values)


@checked(path=PATH)
def load(path) -> HandleModel:
    """A model saved by HandleModel.save."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            return HandleModel.from_arrays({key: stored[key] for key in stored.files})
    except (OSError, ValueError) as exc:
        if isinstance(exc, SkinkitError):
            raise
        raise SkinkitError(f"{path}: not a handle model ({exc})") from None
