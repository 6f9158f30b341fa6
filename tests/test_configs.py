"""recondreamer.configs: the one conversion between config dataclasses and plain data."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import yaml

from recondreamer.configs import DEFAULT_WORKFLOW_CONFIG, check_workflow_config, from_dict, layer, read_yaml_mapping, to_dict, workflow_config
from recondreamer.errors import RecondreamerError
from recondreamer.evaluation.config import MODEL_CONFIGS
from recondreamer.recon.config import ReconConfig, make_config
from recondreamer.generative import config as generative


@dataclasses.dataclass(frozen=True)
class Inner:
    size: tuple[int, int] = (2, 3)
    names: tuple[str, ...] = ("a",)


@dataclasses.dataclass(frozen=True)
class Outer:
    inner: Inner = dataclasses.field(default_factory=Inner)
    optional: Inner | None = None
    pairs: tuple[tuple[int, int], ...] = ((1, 2),)
    rate: float = 0.5


ALL_CONFIGS = [
    make_config("street", "quick"),
    make_config("s3", "paper"),
    *(cls() for cls in MODEL_CONFIGS.values()),
    *(cls() for cls in (generative.AutoencoderConfig, generative.UNetConfig, generative.DiffusionConfig,
                        generative.TrainConfig, generative.MaskConfig, generative.RestoreConfig, generative.RefinerConfig)),
]


class TestToDict:
    def test_json_ready(self):
        plain = to_dict(Outer(optional=Inner()))
        assert plain == {"inner": {"size": [2, 3], "names": ["a"]}, "optional": {"size": [2, 3], "names": ["a"]},
                         "pairs": [[1, 2]], "rate": 0.5}
        assert json.loads(json.dumps(plain)) == plain

    def test_refuses_a_class_or_a_plain_object(self):
        with pytest.raises(TypeError):
            to_dict(Outer)
        with pytest.raises(TypeError):
            to_dict({"rate": 1.0})


class TestFromDict:
    @pytest.mark.parametrize("config", ALL_CONFIGS, ids=lambda c: type(c).__name__)
    def test_every_project_config_round_trips_through_json(self, config):
        assert from_dict(type(config), json.loads(json.dumps(to_dict(config)))) == config

    def test_nested_dataclasses_and_tuples_are_rebuilt(self):
        config = Outer(inner=Inner(size=(4, 5), names=("x", "y")), optional=Inner(), pairs=((1, 2), (3, 4)))
        back = from_dict(Outer, to_dict(config))
        assert back == config and isinstance(back.inner, Inner) and back.pairs == ((1, 2), (3, 4))
        assert from_dict(Outer, {**to_dict(config), "optional": None}).optional is None

    def test_unknown_and_missing_fields_are_named(self):
        values = to_dict(Outer())
        with pytest.raises(RecondreamerError, match=r"Outer: unknown field\(s\) \['bogus'\]"):
            from_dict(Outer, {**values, "bogus": 1})
        del values["rate"]
        with pytest.raises(RecondreamerError, match=r"Outer: missing field\(s\) \['rate'\]"):
            from_dict(Outer, values)
        del values["inner"]["names"]
        with pytest.raises(RecondreamerError, match=r"Inner: missing field\(s\) \['names'\]"):
            from_dict(Outer, {**values, "rate": 1.0})

    def test_partial_values_take_the_defaults(self):
        assert from_dict(Outer, {"rate": 2.0, "inner": {"size": [7, 8]}}, partial=True) == Outer(inner=Inner(size=(7, 8)), rate=2.0)
        assert from_dict(ReconConfig, {"iterations": 3}, partial=True).iterations == 3

    def test_not_a_mapping(self):
        with pytest.raises(RecondreamerError, match="Outer: expected a mapping of fields, got list"):
            from_dict(Outer, [1, 2])


REPO = Path(__file__).resolve().parents[1]
OVERRIDE_CONFIGS = sorted(path.name for path in (REPO / "config").glob("*.yaml") if path.name != DEFAULT_WORKFLOW_CONFIG.name)


class TestLayer:
    def test_mappings_merge_and_other_values_replace(self):
        base = {"a": {"x": 1, "y": [1, 2]}, "b": 2, "synthetic": {"preset": "compact", "segments": {"s1": 1, "s2": 2}}}
        override = {"a": {"y": [3]}, "synthetic": {"segments": {"q": 9}}}
        assert layer(base, override) == {"a": {"x": 1, "y": [3]}, "b": 2, "synthetic": {"preset": "compact", "segments": {"q": 9}}}
        assert base["a"] == {"x": 1, "y": [1, 2]}  # the inputs are left as they were

    def test_later_files_win(self, tmp_path):
        (tmp_path / "config").mkdir()
        (tmp_path / DEFAULT_WORKFLOW_CONFIG).write_text("results_dir: results\nrecon: {seed: 0, iterations: 700}\n")
        (tmp_path / "one.yaml").write_text("recon: {seed: 1}\n")
        (tmp_path / "two.yaml").write_text("recon: {seed: 2}\nresults_dir: elsewhere\n")
        assert workflow_config("one.yaml", "two.yaml", root=tmp_path) == {"results_dir": "elsewhere", "recon": {"seed": 2, "iterations": 700}}

    def test_unreadable_files_are_named(self, tmp_path):
        (tmp_path / "list.yaml").write_text("- a\n")
        with pytest.raises(RecondreamerError, match="list.yaml: a config file must hold a mapping of keys, got list"):
            read_yaml_mapping(tmp_path / "list.yaml")
        (tmp_path / "broken.yaml").write_text("a: [\n")
        with pytest.raises(RecondreamerError, match="broken.yaml: not a readable YAML config"):
            read_yaml_mapping(tmp_path / "broken.yaml")
        assert read_yaml_mapping(_empty(tmp_path)) == {}


def _empty(tmp_path: Path) -> Path:
    (tmp_path / "empty.yaml").write_text("")
    return tmp_path / "empty.yaml"


SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"


class TestCheckWorkflowConfig:
    """A bad value names the config file that set it, the key and the problem."""

    @staticmethod
    def layered(tmp_path, override: dict, command_line: dict | None = None):
        (tmp_path / "mine.yaml").write_text(yaml.safe_dump(override))
        sources = [REPO / DEFAULT_WORKFLOW_CONFIG, REPO / "config" / "quick.yaml", tmp_path / "mine.yaml"]
        config = workflow_config(*sources[1:], root=REPO)
        return layer(config, command_line or {}), sources

    def test_the_file_that_set_the_bad_value_is_named(self, tmp_path):
        config, sources = self.layered(tmp_path, {"recon": {"iterations": -5}})
        with pytest.raises(RecondreamerError, match=r"mine\.yaml: config key recon\.iterations: -5 is less than the minimum of 1"):
            check_workflow_config(config, SCHEMA, sources)

    def test_a_value_from_the_command_line_is_put_down_to_it(self, tmp_path):
        config, sources = self.layered(tmp_path, {}, {"source": "bogus"})
        with pytest.raises(RecondreamerError, match=r"^--config .*config key source: 'bogus' is not one of"):
            check_workflow_config(config, SCHEMA, sources)

    def test_a_valid_layered_config_passes(self, tmp_path):
        config, sources = self.layered(tmp_path, {"recon": {"iterations": 7}})
        check_workflow_config(config, SCHEMA, sources)


class TestShippedConfigs:
    def test_the_default_config_holds_every_key_of_the_schema(self):
        config = read_yaml_mapping(REPO / DEFAULT_WORKFLOW_CONFIG)
        check_workflow_config(config, SCHEMA, [REPO / DEFAULT_WORKFLOW_CONFIG])  # no defaults in the schema: every key is required

    @pytest.mark.parametrize("name", OVERRIDE_CONFIGS)
    def test_override_files_set_only_what_differs_from_the_default(self, name):
        default = read_yaml_mapping(REPO / DEFAULT_WORKFLOW_CONFIG)
        same = []

        def walk(override: dict, base: dict, prefix: str) -> None:
            for key, value in override.items():
                assert key in base, f"config/{name}: {prefix}{key} is not a key of the default config"
                if isinstance(value, dict) and isinstance(base[key], dict) and f"{prefix}{key}" not in ("synthetic.segments", "waymo.segments", "restorer.checkpoints"):
                    walk(value, base[key], f"{prefix}{key}.")
                elif value == base[key]:
                    same.append(f"{prefix}{key}")

        walk(yaml.safe_load((REPO / "config" / name).read_text()), default, "")
        assert not same, f"config/{name} repeats the default's value of {same}"
        assert workflow_config(f"config/{name}", root=REPO)["results_dir"] != default["results_dir"]  # never the default run's results
