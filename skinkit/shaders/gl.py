"""Runs skinkit's shaders through moderngl (an OpenGL 4.3 context: a GPU, or Mesa's llvmpipe headless through EGL):
the test suite checks them against the C runtime, the benchmark times them. moderngl is imported only here."""
from __future__ import annotations

import numpy as np

from . import source

WORK_GROUP = 64  # skin_compute.glsl's local_size_x


def create_context():
    """A standalone OpenGL 4.3+ context: EGL first (headless, llvmpipe without a GPU), then the default backend.
    Raises RuntimeError saying why when neither gives one."""
    import moderngl
    reasons = []
    for backend in ("egl", None):
        try:
            kwargs = {"backend": backend} if backend else {}
            return moderngl.create_context(standalone=True, require=430, **kwargs)
        except Exception as exc:  # each backend fails in its own way (no libEGL, no display, GL too old)
            reasons.append(f"{backend or 'default'}: {exc}")
    raise RuntimeError("no OpenGL 4.3 context: " + "; ".join(reasons))


class ComputeSkinner:
    """skin_compute.glsl over one skinkit.runtime.RuntimePack uploaded once; skin() uploads the instances' bone
    matrices and fractions and reads the outputs back."""

    def __init__(self, ctx, pack):
        self.ctx, self.pack = ctx, pack
        self.program = ctx.compute_shader(source("skin_compute"))
        tangents = pack.tangents if pack.tangents is not None else np.zeros(16, np.float32)
        self.static = [ctx.buffer(np.ascontiguousarray(a).tobytes()) for a in
                       (pack.offsets, pack.bones, pack.positions, tangents)]

    def prepare(self, meshes, fractions, matrices, tangents: bool = False):
        """Uploads and binds one batch: instances drawing meshes (I,) at fractions (I,) with matrices (I, B, 12)
        float32. Returns dispatch(), which runs the shader and waits for it (glFinish); read() then gives the
        outputs."""
        pack, ctx = self.pack, self.ctx
        meshes = np.asarray(meshes, np.int32)
        counts = pack.vertex_counts[meshes]
        output_starts = np.concatenate(([0], np.cumsum(counts))).astype(np.int32)
        instances = np.stack([pack.mesh_starts[meshes], counts, output_starts[:-1], np.zeros_like(counts)], 1)
        self._total = int(output_starts[-1])
        self._tangents = bool(tangents)
        self._dynamic = [ctx.buffer(np.ascontiguousarray(matrices, np.float32).tobytes()),
                         ctx.buffer(np.ascontiguousarray(instances, np.int32).tobytes()),
                         ctx.buffer(np.ascontiguousarray(fractions, np.float32).tobytes())]
        self._outputs = [ctx.buffer(reserve=max(12 * self._total, 4)) for _ in range(3)]
        for binding, buffer in enumerate(self.static + self._dynamic + self._outputs):
            buffer.bind_to_storage_buffer(binding)
        self.program["u_bone_count"] = pack.bone_count
        self.program["u_tangents"] = self._tangents
        groups = max(int(counts.max(initial=0) + WORK_GROUP - 1) // WORK_GROUP, 1)

        def dispatch():
            self.program.run(groups, len(meshes), 1)
            ctx.finish()

        return dispatch

    def read(self):
        """(positions (V, 3), (tangent_0, tangent_1) or None) of the prepared batch, which is then released."""
        total = self._total
        read = [np.frombuffer(b.read(), np.float32)[:3 * total].reshape(total, 3) for b in self._outputs]
        for buffer in self._dynamic + self._outputs:
            buffer.release()
        self._dynamic, self._outputs = [], []
        return read[0], (read[1], read[2]) if self._tangents else None

    def skin(self, meshes, fractions, matrices, tangents: bool = False):
        """prepare, dispatch and read in one: the outputs back to back as skinkit.runtime.skin orders them."""
        self.prepare(meshes, fractions, matrices, tangents)()
        return self.read()

    def release(self):
        for buffer in self.static + getattr(self, "_dynamic", []) + getattr(self, "_outputs", []):
            buffer.release()
        self.program.release()


def vertex_shader_skin(ctx, joints, p, matrices, dp=None, fraction: float = 0.0) -> np.ndarray:
    """skin_vertex.glsl through transform feedback: joints (V, S) uint, p and dp (V, S, 4) per slot (S = 4 or 8)
    as skinkit's glTF export lays them out, matrices (B, 12): (V, 3) model-space positions."""
    import moderngl
    slots = p.shape[1]
    defines = {"SKINKIT_SLOTS": slots}
    if dp is not None:
        defines["SKINKIT_GEOMORPH"] = ""
    program = ctx.program(vertex_shader=source("skin_vertex", defines), varyings=["skinned_position"])
    program["u_view_projection"].write(np.eye(4, dtype=np.float32).tobytes())
    if dp is not None:
        program["u_lod_fraction"] = float(fraction)
    count = len(joints)
    joints = np.ascontiguousarray(joints, np.uint32)
    columns = [(joints[:, :4], "4u", "JOINTS_0")]
    if slots > 4:
        columns.append((joints[:, 4:8].astype(np.float32), "4f", "_SKINKIT_JOINTS_1"))  # as the glTF export writes it
    columns += [(p[:, j], "4f", f"_SKINKIT_P_{j}") for j in range(slots)]
    if dp is not None:
        columns += [(dp[:, j], "4f", f"_SKINKIT_DP_{j}") for j in range(slots)]
    buffers = [ctx.buffer(np.ascontiguousarray(a, np.uint32 if f == "4u" else np.float32).tobytes())
               for a, f, _ in columns]
    vao = ctx.vertex_array(program, [(b, f, name) for b, (_, f, name) in zip(buffers, columns)])
    bones = ctx.buffer(np.ascontiguousarray(matrices, np.float32).tobytes())
    bones.bind_to_storage_buffer(4)
    out = ctx.buffer(reserve=12 * count)
    target = ctx.simple_framebuffer((1, 1))  # a surfaceless context has no default framebuffer: draws are dropped
    target.use()
    vao.transform(out, mode=moderngl.POINTS, vertices=count)
    positions = np.frombuffer(out.read(), np.float32).reshape(count, 3).copy()
    for resource in [vao, program, bones, out, target, *buffers]:
        resource.release()
    return positions
