"""The partial library: clips cut through the index equal the full build's, bit for bit."""

import json

import numpy as np
import pytest

from m2h_ros.core.sounds import partial
from m2h_ros.core.sounds.library import SoundLibraryConfig
from m2h_ros.core.world.episodes import EpisodeConfig, generate_episodes
from m2h_ros.errors import CacheError


@pytest.fixture
def index(small_library, tmp_path):
    return partial.write_index(small_library, tmp_path / "index.json")


def test_the_shipped_index_is_of_the_default_library():
    config = SoundLibraryConfig()
    infos = partial.read_index(config)
    assert len({i.clip_id for i in infos}) == len(infos) > 0
    for split in ("heard", "unheard"):
        rows = sorted(i.row for i in infos if i.split == split)
        assert rows == list(range(config.clips_per_class(split) * len({i.cls for i in infos})))


def test_cut_clips_equal_the_full_build_and_episodes_match(small_library, index, sound_sources, tmp_path,
                                                          monkeypatch):
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path / "data"))
    config = SoundLibraryConfig.small()
    listing = partial.index_library(config, index=index)
    assert listing.fingerprint == small_library.fingerprint and not listing.complete
    episode_config = EpisodeConfig(task="near_target", scene_split="test", sound_split="unheard", count=6,
                                   scene_preset="small", min_source_distance=2.0)
    episodes = generate_episodes(episode_config, listing)
    assert [e.source_clips for e in episodes] == [e.source_clips for e in generate_episodes(episode_config,
                                                                                          small_library)]
    first = sorted({c for e in episodes[:2] for c in e.source_clips})
    library = partial.build_partial(config, first, index=index, sources=sound_sources)
    more = sorted({c for e in episodes for c in e.source_clips})
    library = partial.build_partial(config, more, index=index, sources=sound_sources)  # adds to the first
    assert library.present == frozenset(more) and partial.load_partial(config).present == frozenset(more)
    for clip_id in more:
        np.testing.assert_array_equal(library.clip(clip_id), small_library.clip(clip_id))
    absent = next(i.clip_id for i in small_library.infos("heard") if i.clip_id not in more)
    with pytest.raises(CacheError, match=f"clip {absent}: .* holds only the {len(more)} clips"):
        library.clip(absent)
    with pytest.raises(CacheError, match="build the whole library"):
        library.clips("heard")


def test_an_index_of_another_library_or_decoder_is_refused(small_library, index, sound_sources, tmp_path,
                                                          monkeypatch):
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path / "data"))
    with pytest.raises(CacheError, match="index .* is of library"):
        partial.read_index(SoundLibraryConfig(), index)
    document = json.loads(index.read_text())
    document["clips"][0]["raw_power"] *= 1.01  # as if the sources decoded differently here
    index.write_text(json.dumps(document))
    with pytest.raises(CacheError, match=f"clip {document['clips'][0]['clip_id']}: .* decodes to window power"):
        partial.build_partial(SoundLibraryConfig.small(), [document["clips"][0]["clip_id"]], index=index,
                              sources=sound_sources)
    with pytest.raises(CacheError, match="not in the sound library index"):
        partial.build_partial(SoundLibraryConfig.small(), ["nope/heard/0000"], index=index, sources=sound_sources)
    (partial.partial_path(SoundLibraryConfig.small())).mkdir(parents=True)
    (partial.partial_path(SoundLibraryConfig.small()) / "manifest.json").write_text("{")
    with pytest.raises(CacheError, match="corrupt"):
        partial.load_partial(SoundLibraryConfig.small())


def test_the_pipeline_cuts_only_its_episodes_clips_when_the_library_is_not_built(sound_sources, tmp_path,
                                                                                 monkeypatch):
    from m2h_ros import sim_world
    from m2h_ros.node_configs import SimConfig

    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("M2H_SOUND_SOURCES", str(sound_sources))
    config = SimConfig(num_episodes=2, first_episode=5)
    with pytest.raises(CacheError):
        sim_world.sound_library("")  # nothing built yet: the node names the build command
    library = sim_world.prepare_library(config)
    episodes = sim_world.sim_episodes(config, library)
    assert library.present == frozenset(c for e in episodes for c in e.source_clips)
    assert sim_world.sound_library("").present == library.present  # what the sim node loads
