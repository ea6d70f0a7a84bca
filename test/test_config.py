"""Node configs: validation in __post_init__, and the params YAML files load into them."""

import dataclasses
from pathlib import Path

import pytest
import yaml

from m2h_ros import node_configs
from m2h_ros.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
# every node with a params file
NODE_CONFIGS = {**node_configs.NODE_CONFIGS, **node_configs.ROBOT_CONFIGS,
                "audio_common_adapter": node_configs.AudioCommonAdapterConfig}


@pytest.mark.parametrize("node", sorted(NODE_CONFIGS))
def test_params_file_sets_every_field(node):
    config_type = NODE_CONFIGS[node]
    config = config_type.from_yaml(ROOT / "params" / f"{node}.yaml", node)
    assert isinstance(config, config_type)
    written = yaml.safe_load((ROOT / "params" / f"{node}.yaml").read_text())[node]["ros__parameters"]
    assert set(written) == {f.name for f in dataclasses.fields(config_type)}


@pytest.mark.parametrize("config_type", NODE_CONFIGS.values())
def test_every_field_is_documented(config_type):
    for f in dataclasses.fields(config_type):
        assert len(f.metadata["description"]) > 10, f.name


def test_range_type_and_choice_errors():
    with pytest.raises(ConfigError, match=r"SimConfig.num_episodes = 0: must be >= 1"):
        node_configs.SimConfig(num_episodes=0)
    with pytest.raises(ConfigError, match=r"SimConfig.task = 'far': must be one of"):
        node_configs.SimConfig(task="far")
    with pytest.raises(ConfigError, match=r"expected int"):
        node_configs.SimConfig(num_episodes=2.5)
    with pytest.raises(ConfigError, match=r"must be finite"):
        node_configs.SimConfig(step_timeout_s=float("nan"))
    with pytest.raises(ConfigError, match=r"expected a list of str"):
        node_configs.RecorderConfig(topics=(1, 2))


def test_ints_are_accepted_for_floats_and_lists_for_tuples():
    assert node_configs.SimConfig(step_timeout_s=3).step_timeout_s == 3.0
    assert node_configs.RecorderConfig(topics=["/a"]).topics == ("/a",)


def test_unknown_key_and_missing_section(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text("sim_node:\n  ros__parameters:\n    tsak: near_target\n")
    with pytest.raises(ConfigError, match="unknown SimConfig setting.*tsak"):
        node_configs.SimConfig.from_yaml(bad, "sim_node")
    with pytest.raises(ConfigError, match="no 'other_node: ros__parameters:' section"):
        node_configs.SimConfig.from_yaml(bad, "other_node")
    bad.write_text("sim_node: [unclosed\n")
    with pytest.raises(ConfigError, match="cannot read params file"):
        node_configs.SimConfig.from_yaml(bad, "sim_node")


def test_a_mistyped_name_names_the_nearest_setting():
    with pytest.raises(ConfigError, match=r"num_episode \(did you mean num_episodes\?\)"):
        node_configs.SimConfig.from_dict({"num_episode": 1})
    with pytest.raises(ConfigError, match=r"setting\(s\): zzz; known"):  # nothing near: no guess
        node_configs.SimConfig.from_dict({"zzz": 1})


def test_files_a_setting_names_must_exist(tmp_path):
    with pytest.raises(ConfigError, match=r"SimConfig.head = '/nonexistent.sofa': no such file \(a SOFA HRIR file\)"):
        node_configs.SimConfig(head="sofa:/nonexistent.sofa")
    with pytest.raises(ConfigError, match=r"SeparatorNodeConfig.checkpoint = '/none.pt': no such file"):
        node_configs.SeparatorNodeConfig(checkpoint="/none.pt")
    checkpoint = tmp_path / "policy.pt"
    checkpoint.write_bytes(b"")
    assert node_configs.ControllerConfig(checkpoint=str(checkpoint)).checkpoint == str(checkpoint)
