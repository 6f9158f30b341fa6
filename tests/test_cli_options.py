"""recondreamer.cli_options: command-line options generated from dataclass configs."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

from recondreamer.cli import build_parser
from recondreamer.cli_options import add_config_options, apply_options, field_comments
from recondreamer.errors import ConfigValueError, RecondreamerError


@dataclass(frozen=True)
class Example:
    steps: int = 10  # training steps
    # A comment above a field describes it
    # over two lines.
    rate: float = 0.5
    flag: bool = True
    size: tuple[int, int] = (2, 3)
    names: tuple[str, ...] = ("a",)
    bare: int = 1

    def check(self) -> None:
        if self.steps < 1:
            raise ConfigValueError("steps", f"must be >= 1, got {self.steps}")


NAMES = ("steps", "rate", "flag", "size", "names", "bare")


def parser_for(**kwargs) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    add_config_options(parser, Example, NAMES, **kwargs)
    return parser


class TestFieldComments:
    def test_beside_above_and_none(self):
        comments = field_comments(Example)
        assert comments["steps"] == "training steps"
        assert comments["rate"] == "A comment above a field describes it over two lines."
        assert comments["bare"] == ""


class TestOptions:
    def test_types_and_help(self):
        parser = parser_for()
        args = parser.parse_args(["--steps", "3", "--rate", "0.25", "--flag", "off", "--size", "4", "5", "--names", "x", "y"])
        assert (args.steps, args.rate, args.flag, args.size, args.names, args.bare) == (3, 0.25, False, [4, 5], ["x", "y"], None)
        text = parser.format_help()
        assert "training steps (default: 10)" in text and "(default: on)" in text and "(default: 2 3)" in text
        assert "bare (default: 1)" in text

    def test_defaults_shown_from_an_instance_or_texts(self):
        assert "(default: 99)" in parser_for(defaults=Example(steps=99)).format_help()
        text = parser_for(defaults={"*": "the checkpoint's", "rate": "0.1"}).format_help()
        assert "training steps (default: the checkpoint's)" in text and "(default: 0.1)" in text

    def test_prefix(self):
        parser = argparse.ArgumentParser()
        add_config_options(parser, Example, ("steps",), prefix="mask-")
        args = parser.parse_args(["--mask-steps", "4"])
        assert apply_options(args, Example(), ("steps",), prefix="mask-").steps == 4

    def test_bad_values_are_refused_by_argparse(self, capsys):
        with pytest.raises(SystemExit):
            parser_for().parse_args(["--flag", "maybe"])
        assert "expected on or off" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            parser_for().parse_args(["--size", "1"])

    def test_unknown_field(self):
        with pytest.raises(ValueError, match="has no field"):
            add_config_options(argparse.ArgumentParser(), Example, ("nope",))


class TestApplyOptions:
    def test_only_given_options_replace(self):
        args = parser_for().parse_args(["--size", "7", "8", "--flag", "off"])
        assert apply_options(args, Example(rate=0.9), NAMES) == Example(rate=0.9, size=(7, 8), flag=False)

    def test_the_configs_check_names_the_flag(self):
        args = parser_for().parse_args(["--steps", "0"])
        with pytest.raises(RecondreamerError, match=r"^--steps must be >= 1, got 0$"):
            apply_options(args, Example(), NAMES)


class TestGeneratedCommands:
    @pytest.mark.parametrize("command", ["train-autoencoder", "pretrain-world-model", "train-restorer", "train-refiner", "train-eval-models"])
    def test_every_generated_option_shows_a_description_and_its_default(self, command):
        subparsers = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
        parser = subparsers.choices[command]
        generated = [a for group in parser._action_groups if group.title.endswith(("options", ")")) and "Config" in group.title
                     for a in group._group_actions]
        assert generated
        for action in generated:
            assert "(default: " in action.help and not action.help.startswith(action.dest.replace("_", " ") + " ("), action.option_strings
