"""Episode generation: placement rules, scenarios, determinism, files."""

import json

import numpy as np
import pytest

from m2h_ros.core.world.episodes import (
    SCENARIOS,
    EpisodeConfig,
    episodes_for,
    generate_episodes,
    load_episodes,
    save_episodes,
)
from m2h_ros.errors import ConfigError, EpisodeError


def test_near_target_rules(folder_library):
    config = EpisodeConfig(task="near_target", count=60, seed=3)
    episodes = generate_episodes(config, folder_library)
    assert len(episodes) == 60 and len({e.episode_id for e in episodes}) == 60
    for e in episodes:
        geodesic = e.scene().grid.geodesic
        assert geodesic[e.source_nodes[0], e.source_nodes[1]] >= 8.0
        assert 0 < geodesic[e.start_node, e.target_node] <= 3.0
        assert e.start_node not in e.source_nodes
        assert e.max_steps == 20 and e.target_category in ("speech", "music")
        for clip, category in zip(e.source_clips, e.source_categories):
            info = folder_library.info(clip)
            assert info.split == "unheard" and info.category == category
    assert {e.scene_index for e in episodes} == {0, 1, 2}  # round-robin over the split's scenes


def test_far_target_rules(folder_library):
    episodes = generate_episodes(EpisodeConfig(task="far_target", count=30, seed=1), folder_library)
    for e in episodes:
        assert e.scene().grid.geodesic[e.start_node, e.target_node] >= 6.0
        assert e.max_steps == 100


@pytest.mark.parametrize("scenario", [s for s in SCENARIOS if s != "any"])
def test_scenarios(folder_library, scenario):
    episodes = generate_episodes(EpisodeConfig(scenario=scenario, count=10, sound_split="heard"),
                                 folder_library)
    assert {e.source_categories for e in episodes} == {SCENARIOS[scenario]}


def test_any_scenario_mixes_categories(folder_library):
    episodes = generate_episodes(EpisodeConfig(count=200), folder_library)
    assert {e.target_category for e in episodes} == {"speech", "music"}
    assert {e.source_categories[1] for e in episodes} == {"speech", "music", "background"}


def test_deterministic_and_seed_sensitive(folder_library):
    a = generate_episodes(EpisodeConfig(count=20, seed=5), folder_library)
    b = generate_episodes(EpisodeConfig(count=20, seed=5), folder_library)
    c = generate_episodes(EpisodeConfig(count=20, seed=6), folder_library)
    assert a == b and a != c


def test_thousand_episodes_and_two_distractors(folder_library):
    episodes = generate_episodes(EpisodeConfig(count=1000, min_source_distance=4.0, n_distractors=2),
                                 folder_library)
    assert len(episodes) == 1000
    for e in episodes[:50]:
        geodesic = e.scene().grid.geodesic
        pairs = [(i, j) for i in range(3) for j in range(i + 1, 3)]
        assert all(geodesic[e.source_nodes[i], e.source_nodes[j]] >= 4.0 for i, j in pairs)


def test_impossible_placement_is_explained(folder_library):
    with pytest.raises(EpisodeError, match="cannot hold 2 sources 100.0 m apart"):
        generate_episodes(EpisodeConfig(count=1, min_source_distance=100.0), folder_library)


def test_invalid_config():
    with pytest.raises(ConfigError, match="task"):
        EpisodeConfig(task="nowhere")
    with pytest.raises(ConfigError, match="count"):
        EpisodeConfig(count=0)


def test_file_round_trip_and_errors(folder_library, tmp_path, monkeypatch):
    config = EpisodeConfig(count=12, seed=2)
    episodes = generate_episodes(config, folder_library)
    path = save_episodes(tmp_path / "e.json", episodes, config=config, library=folder_library)
    assert load_episodes(path, library=folder_library) == episodes
    document = json.loads(path.read_text())
    document["library"] = "0" * 16
    path.write_text(json.dumps(document))
    with pytest.raises(EpisodeError, match="generated for sound library"):
        load_episodes(path, library=folder_library)
    path.write_text("{not json")
    with pytest.raises(EpisodeError, match="corrupt"):
        load_episodes(path)
    with pytest.raises(EpisodeError, match="does not exist"):
        load_episodes(tmp_path / "missing.json")
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path / "data"))
    first = episodes_for(config, folder_library)
    assert list((tmp_path / "data" / "episodes").rglob("*.json"))
    assert episodes_for(config, folder_library) == first == episodes
    assert np.all([e.scene_split == "test" for e in first])
