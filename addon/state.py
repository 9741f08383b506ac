"""What the add-on remembers during a session and never saves: the last comparison per mesh and the culling spheres
drawn in the viewport.

Entries are keyed by the object's session_uid, which no other object has in this session and which does not survive
opening a file; `clear` (a load_post handler, registered with the add-on) also forgets everything when a file is
loaded, so nothing is shown on an object of another file that has the same name.
"""
from bpy.app.handlers import persistent

#: Results of the last "Compare with Armature" per object, shown in the panel.
LAST_COMPARISON: dict[int, dict] = {}
#: Culling spheres drawn in the viewport per object: (centre in world space, radius).
CULLING_SPHERES: dict[int, tuple] = {}


def key(scene_object) -> int:
    return scene_object.session_uid


@persistent
def clear(*_arguments) -> None:
    LAST_COMPARISON.clear()
    CULLING_SPHERES.clear()
