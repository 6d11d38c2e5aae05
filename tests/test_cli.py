"""The torchrefl console command: its help lists the subcommands; each subcommand is its python -m module.
(tests/test_install.py runs the installed script.)"""

from torchrefl import cli, plan, train
from torchrefl.rig import __main__ as rig


def test_help_lists_every_subcommand(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in ("train", "plan", "rig"):
        assert f"\n  {name} " in out


def test_a_subcommand_is_its_module(capsys):
    assert cli.main(["train", "--list"]) == 0
    via_cli = capsys.readouterr().out
    assert train.main(["--list"]) == 0
    assert capsys.readouterr().out == via_cli != ""
    assert cli.COMMANDS["train"][0] == train.__name__
    assert cli.COMMANDS["plan"][0] == plan.__name__
    assert cli.COMMANDS["rig"][0] == rig.__name__


def test_errors_of_a_subcommand_keep_its_exit_status(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["train", "nosuchconfig"]) == 2
    assert "nosuchconfig" in capsys.readouterr().err


def test_no_command_or_an_unknown_one_is_a_usage_error(capsys):
    assert cli.main([]) == 2
    assert "train" in capsys.readouterr().err
    assert cli.main(["fit"]) == 2
    assert "unknown command 'fit'" in capsys.readouterr().err
