"""`ftgspp --help` names every `ftgspp bench` subcommand: the list comes from the bench parser."""

from __future__ import annotations

import pytest

from ftgspp.bench import cli
from harness.cli.ftgspp_cmd import main as ftgspp_main


def test_ftgspp_help_lists_every_bench_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.subcommands() == ["render", "train", "scale"]
    assert ftgspp_main(["--help"]) == 0
    assert "  bench render|train|scale [...] " in capsys.readouterr().out


def test_a_new_bench_subcommand_reaches_the_help_by_itself(monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    build = cli.build_parser

    def with_one_more():
        parser = build()
        parser._subparsers._group_actions[0].add_parser("memory", help="peak memory")  # type: ignore[union-attr]
        return parser

    monkeypatch.setattr(cli, "build_parser", with_one_more)
    assert ftgspp_main(["--help"]) == 0
    assert "bench render|train|scale|memory [...]" in capsys.readouterr().out
