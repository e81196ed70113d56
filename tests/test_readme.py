"""The README documents what the CLI has: every verb in the commands table, every option of
``reconstruct`` in its options table, and the test command that ``.ci/run`` runs."""

from __future__ import annotations

from pathlib import Path

from monoavatar.cli import VERBS, build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_every_verb_is_in_the_commands_table() -> None:
    for verb in VERBS:
        assert f"| `{verb}` | `monoavatar {verb}" in README, verb


def test_every_reconstruct_option_is_in_the_options_table() -> None:
    parser = build_parser(only="reconstruct")
    sub = next(a for a in parser._actions if a.dest == "command")
    reconstruct = sub.choices["reconstruct"]  # type: ignore[attr-defined]
    table = README.split("### `reconstruct` options")[1].split("###")[0]
    for action in reconstruct._actions:
        flags = [f for f in action.option_strings if f.startswith("--") and f != "--help"]
        if action.dest in ("output",) or not flags:
            continue
        assert any(f"`{flag}" in table for flag in flags), flags


def test_ci_runs_the_readme_test_command() -> None:
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci in README
