"""The .obj sequences the CLI tests feed in, written as a user's exporter would."""
import os

from skinkit.meshio import write_obj


def write_obj_folder(folder, frames, triangles) -> str:
    """frames (in metres) as folder/tube_001.obj, tube_002.obj, ... in centimetres (so the commands' --sequence-scale
    0.01 reads them back); returns the folder."""
    for index, frame in enumerate(frames, start=1):
        write_obj(os.path.join(str(folder), f"tube_{index:03d}.obj"), frame * 100.0, triangles)
    return str(folder)
