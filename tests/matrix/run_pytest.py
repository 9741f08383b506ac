"""pytest for the Blender matrix: ends the process the way the loaded bpy allows (skinkit.blender.compat), since
bpy 4.2's module teardown can crash after every test has passed and turn the run's exit status into a signal.
Guarded by __main__: the batch smoke's LocalCluster spawns its workers, which import this module again."""
import sys

import pytest


def main() -> None:
    status = int(pytest.main(sys.argv[1:]))
    if "bpy" in sys.modules:
        from skinkit.blender import compat

        compat.exit_process(status)
    sys.exit(status)


if __name__ == "__main__":
    main()
