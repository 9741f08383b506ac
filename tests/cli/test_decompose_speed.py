"""`skinkit decompose` on an .obj folder runs without Blender: bpy is imported only for a .blend, .glb or .abc."""
import json
import os
import subprocess
import sys

from tests.sequences import rigid_chain_sequence

from skinkit.meshio import read_obj_sequence, sequence_files, write_obj

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: Runs the CLI in this interpreter and prints, after its JSON, whether Blender's module was loaded.
PROBE = ("import sys\nfrom skinkit.cli import main\nstatus = main(sys.argv[1:])\n"
         "print(json.dumps({'status': status, 'bpy_loaded': 'bpy' in sys.modules}))\n")


def run_probe(*arguments):
    completed = subprocess.run([sys.executable, "-c", "import json\n" + PROBE, *arguments], capture_output=True,
                               text=True, cwd=ROOT, timeout=300)
    lines = [line for line in completed.stdout.splitlines() if line.strip()]
    return json.loads(lines[0]), json.loads(lines[-1])


def test_an_obj_folder_is_decomposed_and_exported_without_starting_blender(tmp_path):
    frames, triangles, _, _ = rigid_chain_sequence(segments=3, frames=6)
    folder = tmp_path / "sequence"
    folder.mkdir()
    for index, frame in enumerate(frames, start=1):
        write_obj(str(folder / f"frame_{index}.obj"), frame, triangles)
    exported = tmp_path / "exported"
    report, probe = run_probe("decompose", "--sequence", str(folder), "--bones", "3", "--export-frames",
                              str(exported), "--json")
    assert probe == {"status": 0, "bpy_loaded": False}, report
    replayed, read_triangles = read_obj_sequence(sequence_files(str(exported)))
    assert replayed.shape == frames.shape and (read_triangles.size == 0 or read_triangles.shape[1] == 3)
    assert abs(replayed - frames).max() < 1e-4 * abs(frames).max()  # a rigid chain: reconstructed exactly


def test_an_out_blend_does_start_blender(tmp_path):
    frames, triangles, _, _ = rigid_chain_sequence(segments=2, frames=4)
    folder = tmp_path / "sequence"
    folder.mkdir()
    for index, frame in enumerate(frames, start=1):
        write_obj(str(folder / f"frame_{index}.obj"), frame, triangles)
    report, probe = run_probe("decompose", "--sequence", str(folder), "--bones", "2", "--out",
                              str(tmp_path / "rig.blend"), "--json")
    assert probe == {"status": 0, "bpy_loaded": True}, report
    assert os.path.isfile(tmp_path / "rig.blend")
