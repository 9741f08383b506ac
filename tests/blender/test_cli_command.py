"""`blender --command skinkit ...`: the add-on registers the CLI as a Blender command (addon/cli_command.py), and the
command runs the same skinkit CLI inside Blender."""
import json

from tests.conftest import sample_path


def test_the_addon_registers_the_command_and_it_runs_the_cli(addon, capfd):
    from addon import cli_command

    assert cli_command._handle is not None
    capfd.readouterr()
    status = cli_command.execute(["eval", sample_path("arm"), "--frames", "1:3", "--json"])
    # In-process under pytest's capture, Blender's own messages can reach the captured stdout (bpy 4.2 warns about
    # the sample's newer file version); the CLI's output is the one JSON object, last.
    lines = [line for line in capfd.readouterr().out.splitlines() if line.strip()]
    assert status == 0 and sum(line.startswith("{") for line in lines) == 1
    result = json.loads(lines[-1])
    assert result["frames"] == 3 and result["converted_in_memory"] is True


def test_a_failing_command_returns_one_and_help_returns_zero(addon, capfd):
    from addon import cli_command

    assert cli_command.execute(["eval", "no-such-file.blend", "--json"]) == 1
    assert "error" in json.loads(capfd.readouterr().out.strip().splitlines()[-1])
    assert cli_command.execute(["--help"]) == 0
