"""recondreamer.cli_options: command-line options generated from dataclass configs."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

from recondreamer.cli import build_parser, main
from recondreamer.cli_options import add_config_options, apply_options, field_comments
from recondreamer.errors import ConfigValueError, RecondreamerError
from recondreamer.generative.config import RestoreConfig
from recondreamer.methods.pdus import PdusSchedule


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
    @pytest.mark.parametrize("command", ["train-autoencoder", "pretrain-world-model", "train-restorer", "train-refiner", "train-eval-models",
                                         "restore", "dd4d-generate"])
    def test_every_generated_option_shows_a_description_and_its_default(self, command):
        subparsers = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
        parser = subparsers.choices[command]
        generated = [a for group in parser._action_groups if group.title.endswith(("options", ")")) and "Config" in group.title
                     for a in group._group_actions]
        assert generated
        for action in generated:
            assert "(default: " in action.help and not action.help.startswith(action.dest.replace("_", " ") + " ("), action.option_strings


class TestRequiredOptions:
    def test_required_option_is_refused_when_missing_and_says_so_in_its_help(self, capsys):
        parser = argparse.ArgumentParser()
        add_config_options(parser, Example, ("steps", "rate"), required=("steps",))
        assert parser.parse_args(["--steps", "2"]).steps == 2
        with pytest.raises(SystemExit):
            parser.parse_args(["--rate", "0.1"])
        assert "the following arguments are required: --steps" in capsys.readouterr().err
        text = parser.format_help()
        assert "training steps (required)" in text and "(default: 10)" not in text

    def test_required_must_be_one_of_the_options(self):
        with pytest.raises(ValueError, match="required"):
            add_config_options(argparse.ArgumentParser(), Example, ("rate",), required=("steps",))


class TestTrainRecondreamerPdusOptions:
    """--stride, --update-every and --max-offset come from PdusSchedule, --restore-sample-steps and
    --restore-strength from RestoreConfig: help from their field comments, range errors from their
    check(), named by flag before any scene is read."""

    def test_help_shows_each_flag_with_its_field_comment_and_default(self, capsys):
        with pytest.raises(SystemExit) as exit_info:
            main(["train-recondreamer", "--help"])
        assert exit_info.value.code == 0
        text = " ".join(capsys.readouterr().out.split())  # undo argparse's line wrapping
        comments = field_comments(PdusSchedule)
        assert comments["stride"] and comments["update_every"] and comments["max_offset"]
        assert f"--stride STRIDE {comments['stride']} (required)" in text
        assert f"--update-every UPDATE_EVERY {comments['update_every']} (default: iterations / 5, i.e. four updates)" in text
        assert f"--max-offset MAX_OFFSET {comments['max_offset']} (default: 6.0)" in text
        restore = field_comments(RestoreConfig)
        assert f"--restore-sample-steps SAMPLE_STEPS {restore['sample_steps']} (default: the restorer checkpoint's)" in text
        assert f"--restore-strength STRENGTH {restore['strength']} (default: the restorer checkpoint's)" in text

    @pytest.mark.parametrize("options, message", [
        (["--stride", "0"], "--stride must be a positive number of metres, got 0.0"),
        (["--stride", "nan"], "--stride must be a positive number of metres, got nan"),
        (["--stride", "1.5", "--update-every", "0"], "--update-every must be at least 1 step, got 0"),
        (["--stride", "1.5", "--max-offset", "-1"], "--max-offset must be a positive number of metres, got -1.0"),
        (["--stride", "1.5", "--restore-strength", "0"], "--restore-strength must be in (0, 1], got 0.0"),
        (["--stride", "1.5", "--restore-sample-steps", "0"], "--restore-sample-steps must be >= 1, got 0"),
    ])
    def test_a_value_out_of_range_is_an_error_naming_the_flag_before_the_scene_is_read(self, options, message, capsys, tmp_path):
        missing = tmp_path / "missing"  # loading this scene would fail with another message
        argv = ["train-recondreamer", "--scene", str(missing), "--model", "street", "--preset", "quick",
                "--restorer", "truth", "--out", str(tmp_path / "out"), *options]
        assert main(argv) == 1
        error = capsys.readouterr().err
        assert error.strip() == f"recondreamer train-recondreamer: error: {message}"
        assert not (tmp_path / "out").exists()

    def test_a_missing_stride_is_refused_by_argparse(self, capsys, tmp_path):
        with pytest.raises(SystemExit) as exit_info:
            main(["train-recondreamer", "--scene", str(tmp_path), "--model", "street", "--restorer", "truth",
                  "--out", str(tmp_path / "out")])
        assert exit_info.value.code == 2
        assert "the following arguments are required: --stride" in capsys.readouterr().err

    def test_given_flags_reach_the_schedule_and_update_every_defaults_to_a_fifth(self, monkeypatch, tmp_path):
        import recondreamer.methods.loop as loop
        import recondreamer.scene as scene_module

        schedules = []
        monkeypatch.setattr(scene_module, "load_scene", lambda path: object())

        class Stop(Exception):
            pass

        def capture(scene, config, out, restorer, schedule, restore_steps, *, restore_strength, **kwargs):
            schedules.append((config.iterations, schedule, restore_steps, restore_strength))
            raise Stop

        monkeypatch.setattr(loop, "train_recondreamer", capture)
        monkeypatch.setattr("recondreamer.sources.synthetic.truth.TrueViewRenderer", lambda scene: object())
        common = ["train-recondreamer", "--scene", str(tmp_path), "--model", "street", "--restorer", "truth",
                  "--out", str(tmp_path / "out"), "--iterations", "100"]
        for options in (["--stride", "1.5"], ["--stride", "3", "--update-every", "7", "--max-offset", "4.5",
                                                "--restore-sample-steps", "4", "--restore-strength", "0.5"]):
            with pytest.raises(Stop):
                main([*common, *options])
        assert schedules == [  # restore settings not given: None, i.e. the restorer checkpoint's
            (100, PdusSchedule(stride=1.5, update_every=20, iterations=100, max_offset=6.0), None, None),
            (100, PdusSchedule(stride=3.0, update_every=7, iterations=100, max_offset=4.5), 4, 0.5),
        ]
