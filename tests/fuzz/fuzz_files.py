"""Coverage-guided fuzzing (atheris, libFuzzer's engine for Python) of what skinkit reads from outside: OBJ and PC2
files, frame lists typed by people, and the `skinkit` command line's argument and file handling. Any exception
but SkinkitError (the CLI: any exit but its JSON error) is a finding; libFuzzer saves the input that caused it.

    python -m tests.fuzz.fuzz_files -runs=20000 [-max_total_time=60] [CORPUS_DIR]
"""
import contextlib
import os
import sys
import tempfile

import atheris

with atheris.instrument_imports():
    import numpy as np

    from skinkit import SkinkitError
    from skinkit.framelist import parse_frame_list
    from skinkit.meshcache import read_pc2
    from skinkit.meshio import read_obj, read_obj_texture_corners
    from tests.fuzz.cli_outcome import check_command_line

WORK = tempfile.mkdtemp(prefix="skinkit-fuzz-")
OBJ, PC2, OUT = (os.path.join(WORK, name) for name in ("mesh.obj", "cache.pc2", "atlas.obj"))
CLI_FLAGS = ("--charts", "--texture-size", "--margin", "--mode", "--metric", "--segment-in", "--straighten",
             "--sequence", "--object")


def fuzz_readers(data: atheris.FuzzedDataProvider) -> None:
    content = data.ConsumeBytes(data.remaining_bytes())
    for path, readers in ((OBJ, (read_obj, read_obj_texture_corners)), (PC2, (read_pc2,))):
        with open(path, "wb") as file:
            file.write(content if path == OBJ else b"POINTCACHE2\x00" + content)
        for reader in readers:
            with contextlib.suppress(SkinkitError):
                reader(path)


def fuzz_frame_list(data: atheris.FuzzedDataProvider) -> None:
    with contextlib.suppress(SkinkitError):
        assert len(parse_frame_list(data.ConsumeUnicodeNoSurrogates(64))) <= 1_000_000


def fuzz_command_line(data: atheris.FuzzedDataProvider) -> None:
    """`skinkit unwrap MESH --out OUT --json` with fuzzed flags on a small valid or fuzzed mesh, judged by
    cli_outcome.check_command_line."""
    if data.ConsumeBool():
        write_grid(data.ConsumeIntInRange(1, 6))
    else:
        with open(OBJ, "wb") as file:
            file.write(data.ConsumeBytes(200))
    argv = ["unwrap", OBJ, "--out", OUT, "--json"]
    for _ in range(data.ConsumeIntInRange(0, 4)):
        argv += [CLI_FLAGS[data.ConsumeIntInRange(0, len(CLI_FLAGS) - 1)], data.ConsumeUnicodeNoSurrogates(12)]
    check_command_line(argv)


def write_grid(size: int) -> None:
    u, v = np.meshgrid(np.arange(size + 1), np.arange(size + 1))
    vertices = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1)
    index = lambda i, j: i * (size + 1) + j + 1  # noqa: E731 - OBJ's 1-based index
    faces = [(index(i, j), index(i, j + 1), index(i + 1, j + 1), index(i + 1, j))
             for i in range(size) for j in range(size)]
    with open(OBJ, "w") as file:
        file.writelines(f"v {x} {y} {z}\n" for x, y, z in vertices)
        file.writelines(f"f {a} {b} {c} {d}\n" for a, b, c, d in faces)


TARGETS = (fuzz_readers, fuzz_frame_list, fuzz_command_line)


def test_one_input(raw: bytes) -> None:
    data = atheris.FuzzedDataProvider(raw)
    TARGETS[data.ConsumeIntInRange(0, len(TARGETS) - 1)](data)


if __name__ == "__main__":
    atheris.Setup(sys.argv, test_one_input)
    atheris.Fuzz()
