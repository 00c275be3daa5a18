"""`btf-host keygen` and `btf-host linktest`, driven through their own parsers."""
import argparse
import json
import os

import pytest

from radio.keys import load_key
from tools.cli import keygen as cmd_keygen
from tools.cli import linktest as cmd_linktest
from tools.cli.options import CliError


def run(module, argv):
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    return module.run(args)


def test_keygen_writes_a_private_key_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "link.key"
    assert run(cmd_keygen, ["keygen", "--out", str(out)]) == 0
    key = load_key(out)
    assert os.stat(out).st_mode & 0o777 == 0o600
    with pytest.raises(CliError, match="--force"):
        run(cmd_keygen, ["keygen", "--out", str(out)])
    assert run(cmd_keygen, ["keygen", "--out", str(out), "--force"]) == 0
    assert load_key(out) != key


def test_keygen_warns_inside_a_git_work_tree(tmp_path, capsys):
    (tmp_path / ".git").mkdir()
    run(cmd_keygen, ["keygen", "--out", str(tmp_path / "k")])
    assert "git work tree" in capsys.readouterr().err


def test_keygen_into_a_missing_directory_is_a_cli_error(tmp_path):
    with pytest.raises(CliError, match="cannot write"):
        run(cmd_keygen, ["keygen", "--out", str(tmp_path / "nope" / "k")])


def test_linktest_json_reports_the_counters(capsys):
    rc = run(cmd_linktest, ["linktest", "--loss", "0.1", "--ber", "1e-4", "--dup", "0.05",
                            "--reorder", "0.05", "--packets", "60", "--bursty", "--json",
                            "--seed", "3", "--forged", "10"])
    report = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert report["sent"] == report["delivered"] == 60
    assert report["delivered_twice"] == report["corrupted_accepted"] == report["forged_accepted"] == 0
    assert report["rejected"]["tag"] >= 10 and 0 < report["goodput"] <= 1


@pytest.mark.parametrize("argv", [["--loss", "1.2"], ["--packets", "0"], ["--mtu", "10"], ["--ber", "-1"],
                                  ["--packets", "1000000000"], ["--forged", "10000000000"], ["--latency", "nan"]])
def test_linktest_bad_input_is_one_line_naming_the_range(host, argv):
    code, out, err = host("linktest", *argv)
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and err.startswith(f"btf-host linktest: error: {argv[0]} {argv[1]}: ")
    assert "must lie in" in err and "Traceback" not in err
