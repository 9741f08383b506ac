"""The bridge between Blender and skinkit: reading rigs, storing models, converting, previewing, baking.

It imports bpy, so it is imported only inside Blender (the add-on) or with Blender's `bpy` module (the
command line); `import skinkit` alone never imports it.
"""
