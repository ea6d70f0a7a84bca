"""Derived products (spectrogram pictures, the path, pcm-s16 tracks, TF) cost nothing when nobody watches:
the nodes build one only while something subscribes to it, and by default the recorder does not, leaving
them to m2h-derive after the run; with keep_derived it records them live. Both bags show the same."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest
from pipeline_helpers import ROOT, bag_messages, node_env, run_pipeline, tiny_sets

from m2h_ros import topics
from m2h_ros.core.world.episodes import DEFAULT_MAX_STEPS
from m2h_ros.io.derived import absolute

pytestmark = pytest.mark.graph
PICTURES = [absolute(t) for t in (topics.MIXTURE_IMAGE, topics.BINAURAL_IMAGE, topics.MONAURAL_IMAGE,
                                  topics.REFINED_IMAGE)]
WATCHED = absolute(topics.REFINED_IMAGE)
STEPS = DEFAULT_MAX_STEPS["near_target"] + 1  # one near-target episode's observations
VIEWER_MATCH_S = 6.0


def sent(log: str) -> dict[str, int]:
    """What a node's exit summary says it sent of each derived topic."""
    line = re.search(r"derived topics sent \(only while subscribed\): (.*)", log).group(1)
    return {topic: int(count) for topic, count in (item.rsplit(" ", 1) for item in line.split(", "))}


def run(out, data_dir, *extra: str):
    result = run_pipeline(out, data_dir, "--episodes", "1", "--controller", "random", "--set",
                          "controller_node.seed=7", *extra, *tiny_sets())
    assert result.returncode == 0, result.stdout + result.stderr
    logs = {node: (out / "logs" / f"{node}.log").read_text()
            for node in ("sim_node", "separator_node", "evaluator_node", "recorder_node")}
    return result, logs


def test_unwatched_products_are_not_built_and_the_bag_gets_them_after_the_run(small_library, small_data_dir,
                                                                                processes, tmp_path):
    viewer = processes.start([sys.executable, str(ROOT / "test" / "graph" / "topic_counter.py"), WATCHED],
                             env=node_env(small_data_dir), cwd=ROOT / "test" / "graph")
    assert viewer.stdout.readline().strip() == "subscribed"
    # DDS discovery can take about 2 s to match the separator with a viewer that was already running; the
    # start delay lets it match before step 0, so the viewer sees the whole run.
    lazy, logs = run(tmp_path / "lazy", small_data_dir, "--set", f"sim_node.start_delay_s={VIEWER_MATCH_S}")
    code, out, err = processes.interrupt(viewer)
    assert code == 0, err
    received = int(re.search(r"received (\d+)", out).group(1))
    # Only the watched picture was built, for every step; nothing else derived.
    separator = sent(logs["separator_node"])
    assert separator[WATCHED] == received == STEPS
    assert all(separator[t] == 0 for t in PICTURES if t != WATCHED)
    assert sent(logs["evaluator_node"]) == {topics.TARGET_IMAGE: 0}
    assert sent(logs["sim_node"]) == {absolute(topics.PATH): 0}
    recorded = set(re.findall(r"recording (\S+) \[", logs["recorder_node"]))
    assert recorded and not recorded & {*PICTURES, topics.TARGET_IMAGE, absolute(topics.PATH)}
    assert "[run] derived:" in lazy.stdout

    # keep_derived: the recorder subscribes, so every node builds them, and nothing is added afterwards.
    kept, logs = run(tmp_path / "kept", small_data_dir, "--set", "recorder_node.keep_derived=true")
    assert all(count == STEPS for count in sent(logs["separator_node"]).values())
    assert sent(logs["evaluator_node"]) == {topics.TARGET_IMAGE: STEPS}
    assert "[run] derived:" not in kept.stdout

    # The same run, the same pictures and path: derived afterwards or made by the nodes live.
    derived, live = bag_messages(tmp_path / "lazy" / "bag"), bag_messages(tmp_path / "kept" / "bag")
    for topic in [*PICTURES, topics.TARGET_IMAGE]:
        assert len(derived[topic]) == len(live[topic]) == STEPS, topic
        for a, b in zip(derived[topic], live[topic], strict=True):
            assert (a.height, a.width, a.encoding, a.header.frame_id) == (b.height, b.width, b.encoding,
                                                                          b.header.frame_id)
            np.testing.assert_array_equal(a.data, b.data)
    path = absolute(topics.PATH)
    assert len(derived[path]) == len(live[path]) == STEPS
    for a, b in zip(derived[path], live[path], strict=True):
        assert [[(p.x, p.y, p.z) for p in m.points] for m in a.markers] == \
            [[(p.x, p.y, p.z) for p in m.points] for m in b.markers]
