"""Bake Normal Maps and Bake Tangent Maps: the operators (over skinkit.blender.normal_maps, the functions the CLI's
bake-normals and bake-tangent-maps call) and their sub-panel under Level of Detail."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from skinkit.blender import normal_maps, storage
from skinkit.model import SkinkitError

from .common import SidebarPanel
from .operators import DialogJobOperator, active_mesh, refused

#: The image formats by their enum identifiers (skinkit.normal_maps.FORMATS' strings).
FORMAT_OPTION = {"PNG16": "png16", "PNG8": "png8", "EXR": "exr", "EXR_FLOAT": "exr-float"}


def selected_source(context):
    """The selected mesh other than the active one: the high-resolution source."""
    active = context.active_object
    others = [o for o in context.selected_objects if o.type == "MESH" and o != active]
    return others[0] if len(others) == 1 else None


def chain_of(mesh_object):
    return next((c for c in mesh_object.users_collection if normal_maps.REPORT_PROPERTY in c), None)


class SKINKIT_OT_bake_normal_maps(DialogJobOperator, bpy.types.Operator):
    """Bake tangent-space normal maps onto the active mesh or every level of its LOD chain, from the chain's LOD0
    (a ray cast checked against the shared atlas, or the atlas alone) or from a selected high-resolution mesh (ray
    casting within the cage); the images are saved in the folder and wired into each level's material"""

    bl_idname = "skinkit.bake_normal_maps"
    bl_label = "Bake Normal Maps"
    bl_options = {"REGISTER", "UNDO"}

    source: EnumProperty(name="Source", default="LOD0", items=(
        ("LOD0", "LOD0 of the Chain", "The chain's full-detail level: a ray cast along the level's normals within the "
                                      "cage, checked against the shared atlas (the same uv point)"),
        ("LOD0_ATLAS", "LOD0, Atlas Only", "The chain's full-detail level at the same uv point only: the fastest"),
        ("SELECTED", "Selected Mesh", "The selected high-resolution mesh (not the active one), by ray casting along "
                                      "the target's normals within the cage")))
    targets: EnumProperty(name="Targets", default="CHAIN", items=(
        ("CHAIN", "Every Level", "Every level of the active mesh's LOD chain (LOD0 too, from a selected source)"),
        ("ACTIVE", "Active Mesh", "Only the active mesh")))
    resolution: IntProperty(name="Resolution", default=1024, min=8, max=16384, description="Texels per side")
    margin: IntProperty(name="Margin", default=8, min=0, max=127, description="Dilation margin in texels")
    samples: IntProperty(name="Samples", default=2, min=1, max=8, description="N x N samples per texel")
    cage: FloatProperty(name="Cage", default=0.0, min=0.0, unit="LENGTH",
                        description="Ray-cast distance each way along the normal (0: 5% of the target's size)")
    frame: IntProperty(name="Frame", default=-1, min=-1,
                       description="The pose to bake (-1: the current frame)")
    image_format: EnumProperty(name="Format", default="PNG16", items=(
        ("PNG16", "PNG 16-bit", ""), ("PNG8", "PNG 8-bit", ""), ("EXR", "OpenEXR Half", ""),
        ("EXR_FLOAT", "OpenEXR Float", "")))
    directory: StringProperty(name="Folder", default="//", subtype="DIR_PATH",
                              description="Where the images are written ('//': beside the .blend)")
    pack: BoolProperty(name="Pack", default=True, description="Pack the images into the .blend (else link them)")

    @classmethod
    def poll(cls, context):
        mesh_object = active_mesh(context)
        if mesh_object is None:
            return refused(cls, "The active object must be a mesh")
        if not mesh_object.data.uv_layers:
            return refused(cls, "The active mesh needs a UV map (unwrap it or build a LOD chain)")
        return refused(cls, None if chain_of(mesh_object) is not None or selected_source(context) is not None else
                       "Select a high-resolution source mesh, or make the active mesh a LOD level")

    def prepare(self, context):
        target = active_mesh(context)
        source = None
        if self.source == "SELECTED":
            source = selected_source(context)
            if source is None:
                raise SkinkitError("select exactly one high-resolution mesh besides the active one")
        targets = [target]
        if self.targets == "CHAIN":
            chain = chain_of(target)
            if chain is None:
                raise SkinkitError(f"'{target.name}' is in no LOD chain: bake the active mesh only")
            targets = normal_maps.chain_levels(chain)
        folder = bpy.path.abspath(self.directory)
        if self.directory.startswith("//") and not bpy.data.filepath:
            raise SkinkitError("save the .blend first, or choose an absolute folder for the images")
        return normal_maps.prepare_normal_maps(
            targets, source, correspondence="atlas" if self.source == "LOD0_ATLAS" else "guided",
            size=self.resolution, margin=self.margin, samples=self.samples,
            cage=self.cage or None, frame=None if self.frame < 0 else self.frame,
            image_format=FORMAT_OPTION[self.image_format], out_dir=folder, pack=self.pack)

    def write(self, context, mesh_object, solved):
        report = self._job.write(mesh_object, solved, self.seconds_taken())
        messages = []
        for row in report["maps"]:
            level = "WARNING" if row["texels_missed"] else "INFO"
            messages.append((level, f"'{row['object']}': {row['texels_filled']} texels filled, "
                                    f"{row['texels_missed']} missed, mean error {row['mean_angular_error']:.2f} deg "
                                    f"-> {row['path']}"))
        return messages


#: The tangent maps' EXR formats by their enum identifiers (the CLI's --format strings).
TANGENT_FORMAT_OPTION = {"EXR_FLOAT": "exr-float", "EXR": "exr"}


class SKINKIT_OT_bake_tangent_maps(DialogJobOperator, bpy.types.Operator):
    """Bake tangent maps (per texel the animation-space tangents of the chain's LOD0 model, in tiles sharing one
    influence count) for the active mesh or every level of its LOD chain, with the object-space normal map they give
    in the chosen pose and, optionally, their mip chain; the files are written to the folder"""

    bl_idname = "skinkit.bake_tangent_maps"
    bl_label = "Bake Tangent Maps"
    bl_options = {"REGISTER", "UNDO"}

    targets: EnumProperty(name="Targets", default="CHAIN", items=(
        ("CHAIN", "Every Level", "Every level of the active mesh's LOD chain, LOD0 included"),
        ("ACTIVE", "Active Mesh", "Only the active mesh")))
    resolution: IntProperty(name="Resolution", default=256, min=1, max=16384,
                            description="Texels per side (256: the thesis' section 8.6.2)")
    tile: IntProperty(name="Tile", default=8, min=1, max=4096,
                      description="Tile side in texels: a tile's texels share one influence count")
    max_influences: IntProperty(name="Max Influences", default=16, min=1, max=256,
                                description="The most bones a texel may need")
    mip_levels: IntProperty(name="Mip Levels", default=1, min=1, max=15,
                            description="Maps in the mip chain, this one included (each next by the appendix A.1 "
                                        "averaging of 2x2 blocks)")
    frame: IntProperty(name="Frame", default=-1, min=-1,
                       description="The pose of the object-space normal map (-1: the current frame)")
    image_format: EnumProperty(name="Format", default="EXR_FLOAT", items=(
        ("EXR_FLOAT", "OpenEXR Float", ""), ("EXR", "OpenEXR Half", "")))
    directory: StringProperty(name="Folder", default="//", subtype="DIR_PATH",
                              description="Where the maps are written ('//': beside the .blend)")

    @classmethod
    def poll(cls, context):
        mesh_object = active_mesh(context)
        if mesh_object is None:
            return refused(cls, "The active object must be a mesh")
        chain = chain_of(mesh_object)
        if chain is None:
            return refused(cls, "The active mesh must be a level of a LOD chain (Build LOD Chain)")
        levels = normal_maps.chain_levels(chain)
        if not levels or not storage.has_model(levels[0].data):
            return refused(cls, "The chain's LOD0 needs an animation-space model (Fit from Example Poses first)")
        return True

    def prepare(self, context):
        target = active_mesh(context)
        targets = normal_maps.chain_levels(chain_of(target)) if self.targets == "CHAIN" else [target]
        if self.directory.startswith("//") and not bpy.data.filepath:
            raise SkinkitError("save the .blend first, or choose an absolute folder for the maps")
        return normal_maps.prepare_tangent_maps(
            targets, size=self.resolution, tile=self.tile, max_influences=self.max_influences,
            frame=None if self.frame < 0 else self.frame, out_dir=bpy.path.abspath(self.directory),
            image_format=TANGENT_FORMAT_OPTION[self.image_format], mip_levels=self.mip_levels)

    def write(self, context, mesh_object, solved):
        report = self._job.write(mesh_object, solved, self.seconds_taken())
        return [("INFO", f"'{row['object']}': {row['texels_filled']} texels, up to {row['max_tile_influences']} "
                         f"bones a tile, object-space normals within {row['max_angular_error']:.3f} deg "
                         f"-> {row['path']}") for row in report["maps"]]


class SKINKIT_PT_normal_maps(SidebarPanel, bpy.types.Panel):
    bl_label = "Normal Maps"
    bl_parent_id = "SKINKIT_PT_level_of_detail"

    def draw(self, context):
        self.layout.operator(SKINKIT_OT_bake_normal_maps.bl_idname, text="Bake Normal Maps...", icon="TEXTURE")
        self.layout.operator(SKINKIT_OT_bake_tangent_maps.bl_idname, text="Bake Tangent Maps...", icon="TEXTURE")


classes = (SKINKIT_OT_bake_normal_maps, SKINKIT_OT_bake_tangent_maps, SKINKIT_PT_normal_maps)
