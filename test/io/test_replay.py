"""Offline replay scoring (m2h-eval): recomputed scores equal the live ones, differences are found,
damaged bags are read up to their last complete chunk, foreign bags are named, rosbag2-written bags
score the same as ours."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import CRCValidationError
from rosbag2_style import rewrite_as_rosbag2

from m2h_ros import topics
from m2h_ros.core.results import METRICS
from m2h_ros.errors import BagError
from m2h_ros.io.bag import BagWriter
from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import typestore
from m2h_ros.io.replay import ReplayConfig, replay_bag
from m2h_ros.io.synthetic import SyntheticRun, write_synthetic_run
from m2h_ros.replay_cli import main as m2h_eval

NEAR = SyntheticRun(episodes=3, max_steps=4, camera=False)


def same_results(replayed, live):
    assert [r.episode_id for r in replayed] == [r.episode_id for r in live]
    for a, b in zip(replayed, live, strict=True):
        mine, theirs = a.to_dict(), b.to_dict()
        assert mine.keys() == theirs.keys()
        for key, value in mine.items():
            if isinstance(value, float | list) and key != "actions":
                np.testing.assert_allclose(value, theirs[key], atol=1e-9, err_msg=f"{a.episode_id} {key}")
            else:
                assert value == theirs[key], (a.episode_id, key)


@pytest.fixture(scope="module")
def near_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp("near") / "bag"
    return bag, write_synthetic_run(bag, SyntheticRun(episodes=3, max_steps=4))


def test_replay_equals_live(near_bag):
    bag, live = near_bag
    replay = replay_bag(bag)
    same_results(replay.results, live)
    assert replay.ok and replay.problems == [] and replay.notes == []
    assert replay.steps_scored == replay.comparison.steps == 3 * 5
    assert replay.comparison.episodes == 3
    assert replay.comparison.live_only == replay.comparison.replayed_only == 0
    assert replay.stats.complete


def test_estimates_logged_episodes_late_are_still_scored(tmp_path):
    # The separator and evaluator trail the sim by up to max_evaluator_lag (64) observations: here the
    # estimates of an episode come 4 episodes (20 observations) after its own observations.
    live = write_synthetic_run(tmp_path / "bag", SyntheticRun(episodes=6, max_steps=4, camera=False, estimate_lag=20))
    replay = replay_bag(tmp_path / "bag")
    assert replay.ok and replay.problems == []
    same_results(replay.results, live)


def test_batch_size_and_scoring_processes_do_not_change_scores(near_bag):
    bag, live = near_bag
    for batch, processes in ((1, 1), (3, 1), (16, 2), (3, 3)):
        replay = replay_bag(bag, config=ReplayConfig(batch_steps=batch, score_processes=processes))
        same_results(replay.results, live)
        assert replay.ok and all(replay.comparison.max_diff[metric] == 0.0 for metric in METRICS)


def test_far_target_stop_success_and_spl(tmp_path):
    live = write_synthetic_run(tmp_path / "bag", SyntheticRun(episodes=2, task="far_target", max_steps=10,
                                                               stop_after=3, camera=False))
    replay = replay_bag(tmp_path / "bag")
    same_results(replay.results, live)
    assert all(r.success and r.spl == pytest.approx(1.0) and r.steps == 4 for r in replay.results)
    assert replay.ok


def test_a_differing_live_score_is_reported(tmp_path):
    def tamper(episode_id, step, scores):
        changed = episode_id.endswith("000001") and step == 2
        return dataclasses.replace(scores, si_sdr=scores.si_sdr + 0.01) if changed else scores

    write_synthetic_run(tmp_path / "bag", NEAR, live_score=tamper)
    replay = replay_bag(tmp_path / "bag")
    found = {(m.episode_id[-6:], m.step, m.metric) for m in replay.comparison.mismatches}
    # the step itself, and the episode mean that includes it
    assert found == {("000001", 2, "si_sdr"), ("000001", None, "episode_mean_si_sdr")}
    mismatch = next(m for m in replay.comparison.mismatches if m.step == 2)
    assert mismatch.live - mismatch.replayed == pytest.approx(0.01)
    assert not replay.ok
    assert replay_bag(tmp_path / "bag", config=ReplayConfig(atol=0.02)).ok


def test_a_bag_with_the_old_stft_distance_gets_a_note(tmp_path):
    def frobenius_era(episode_id, step, scores):   # what an older evaluator recorded
        return dataclasses.replace(scores, stft_distance=scores.stft_distance * 1000.0)

    write_synthetic_run(tmp_path / "bag", NEAR, live_score=frobenius_era)
    replay = replay_bag(tmp_path / "bag")
    assert {m.metric for m in replay.comparison.mismatches} == {"stft_distance", "episode_stft_distance"}
    assert any("whose STFT distance was a Frobenius norm" in note for note in replay.notes)
    # one differing step is not the old definition: no note
    write_synthetic_run(tmp_path / "one", NEAR, live_score=lambda e, step, scores: frobenius_era(e, step, scores)
                        if step == 1 and e.endswith("000001") else scores)
    assert not any("STFT distance" in note for note in replay_bag(tmp_path / "one").notes)


def killed_copy(bag: Path, target: Path, fraction: float) -> Path:
    """What a SIGKILL leaves: the .mcap cut mid-write, no summary, no footer, no metadata.yaml."""
    target.mkdir()
    data = next(bag.glob("*.mcap")).read_bytes()
    (target / "killed.mcap").write_bytes(data[: int(len(data) * fraction)])
    return target


def test_killed_recorder_bag_scores_its_complete_episodes(tmp_path):
    bag = tmp_path / "bag"
    with BagWriter(bag, flush_period_s=1e-6) as writer:  # a chunk per message, like a slow recorder
        live = write_synthetic_run(bag, NEAR, writer=writer)
    killed = killed_copy(bag, tmp_path / "killed", 0.75)  # cut inside the third episode
    replay = replay_bag(killed)
    same_results(replay.results, live[:2])
    text = "\n".join(map(str, replay.problems))
    assert "no metadata.yaml" in text
    assert "truncated at byte" in text
    assert f"episode {live[2].episode_id} not scored: the bag ends before it does" in text
    assert not replay.stats.complete and replay.comparison.mismatches == []


def test_unflushed_writer_leaves_only_complete_chunks(tmp_path):
    """Without flushing, the open chunk is only in memory: a copy taken now lacks it, but reads."""
    store = typestore()
    writer = BagWriter(tmp_path / "bag", flush_period_s=0.05)
    msg = store.types["m2h_msgs/msg/MotionCommand"]
    header = store.types["std_msgs/msg/Header"](stamp=store.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                                 frame_id="")
    for k in range(3):
        writer.write("/cmd", msg.__msgtype__, k, msg(header=header, episode_id="e", step=k, action=1, controller="c"))
    writer.flush()
    writer.write("/cmd", msg.__msgtype__, 9, msg(header=header, episode_id="e", step=9, action=1, controller="c"))
    snapshot = killed_copy(tmp_path / "bag", tmp_path / "snap", 1.0)
    writer.close()
    stream = BagStream(snapshot)
    assert [m.log_time for m in stream.messages()] == [0, 1, 2]
    assert stream.stats.chunks == 1 and not stream.stats.complete


def test_corrupt_record_stops_reading_there(tmp_path):
    bag = tmp_path / "bag"
    with BagWriter(bag, flush_period_s=1e-6) as writer:
        live = write_synthetic_run(bag, NEAR, writer=writer)
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    offset = next(o for o in chunk_offsets(data) if o > 0.6 * len(data))
    data[offset] = 0x42
    mcap.write_bytes(bytes(data))
    replay = replay_bag(bag)
    assert f"corrupt at byte {offset}: opcode 0x42" in "\n".join(map(str, replay.problems))
    same_results(replay.results, live[:1])  # the first episode lies before the damage
    assert any("read " in str(p) and "metadata.yaml lists" in str(p) for p in replay.problems)


def chunk_offsets(data: bytes) -> list[int]:
    """Byte offsets of the chunk records of an intact MCAP file's data section."""
    offsets, pos = [], 8
    while data[pos] not in (0x0F, 0x02):
        if data[pos] == 0x06:
            offsets.append(pos)
        pos += 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
    return offsets


def test_rosbag2_written_bag_scores_the_same(near_bag, tmp_path):
    bag, live = near_bag
    other = rewrite_as_rosbag2(bag, tmp_path / "rosbag2")
    replay = replay_bag(other)
    same_results(replay.results, live)
    assert replay.ok and replay.comparison.steps == 15


def test_split_rosbag2_bag_reads_across_files(near_bag, tmp_path):
    bag, live = near_bag
    other = rewrite_as_rosbag2(bag, tmp_path / "split", split_every=25)  # episodes span files
    assert len(list(other.glob("*.mcap"))) > 5
    replay = replay_bag(other)
    same_results(replay.results, live)
    assert replay.ok and replay.stats.files == len(list(other.glob("*.mcap")))


def test_corrupt_zstd_chunk_is_skipped_and_later_episodes_scored(near_bag, tmp_path):
    bag, live = near_bag
    other = rewrite_as_rosbag2(bag, tmp_path / "rosbag2")
    mcap = next(other.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    chunks = chunk_offsets(data)
    target = chunks[len(chunks) // 2] + 200  # inside the compressed data of a chunk of the second episode
    data[target:target + 64] = bytes(64)
    mcap.write_bytes(bytes(data))
    replay = replay_bag(other)
    text = "\n".join(map(str, replay.problems))
    assert "corrupt chunk" in text and "skipped, never decoded" in text
    scored = {r.episode_id for r in replay.results}
    assert live[0].episode_id in scored and live[2].episode_id in scored and live[1].episode_id not in scored
    same_results(replay.results, [live[0], live[2]])


def test_flipped_payload_bytes_are_named_skipped_and_never_scored(tmp_path):
    bag = tmp_path / "bag"
    with BagWriter(bag, flush_period_s=1e-6) as writer:  # a chunk per message
        live = write_synthetic_run(bag, NEAR, writer=writer)
    mcap_file = next(bag.glob("*.mcap"))
    data = bytearray(mcap_file.read_bytes())
    with mcap_file.open("rb") as stream:
        channels = make_reader(stream).get_summary().channels
    refined = next(c.id for c in channels.values() if c.topic == "/" + topics.REFINED)
    # The chunk with the second episode's first refined estimate (two messages), flipped mid-payload.
    number, offset = [(k + 1, o) for k, o in enumerate(chunk_offsets(data)) if refined in chunk_channels(data, o)][5]
    end = offset + 9 + int.from_bytes(data[offset + 1:offset + 9], "little")
    middle = (offset + end) // 2
    damaged = bytes(data[:middle]) + bytes(b ^ 0xFF for b in data[middle:middle + 8]) + bytes(data[middle + 8:])
    mcap_file.write_bytes(damaged)

    stream = BagStream(bag)
    list(stream.messages())
    problem, count = map(str, stream.problems)
    assert "read 151 of the 153 messages" in count
    assert f"corrupt chunk {number} (bytes {offset}-{end}" in problem and "CRC-32 mismatch" in problem
    assert f"/{topics.REFINED} (1)" in problem.split("lost messages: ")[1]
    with mcap_file.open("rb") as stream, pytest.raises(CRCValidationError):  # the independent reader agrees
        for _ in make_reader(stream, validate_crcs=True).iter_messages():
            pass
    replay = replay_bag(bag)
    same_results(replay.results, [live[0], live[2]])  # the damaged episode is not scored, the others are
    assert m2h_eval([str(bag), "--out", str(tmp_path / "out"), "--no-plots"]) == 3


def chunk_channels(data: bytes, offset: int) -> set[int]:
    """Channels of the messages in an uncompressed chunk."""
    pos = offset + 9 + 28
    pos += 4 + int.from_bytes(data[pos:pos + 4], "little")  # compression string
    end = pos + 8 + int.from_bytes(data[pos:pos + 8], "little")
    pos, channels = pos + 8, set()
    while pos < end:
        if data[pos] == 0x05:
            channels.add(int.from_bytes(data[pos + 9:pos + 11], "little"))
        pos += 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
    return channels


def test_foreign_definition_is_named_and_not_decoded(near_bag, tmp_path):
    bag, _ = near_bag
    from rosbag2_style import rosbag2_definition

    spectrogram = "m2h_msgs/msg/Spectrogram"
    foreign = rosbag2_definition(spectrogram).replace("float32[] data", "float64[] data", 1)
    other = rewrite_as_rosbag2(bag, tmp_path / "foreign", definitions={spectrogram: foreign})
    replay = replay_bag(other)
    text = "\n".join(map(str, replay.problems))
    assert f"topic /separator/refined: {spectrogram} in the bag is not this checkout's definition" in text
    assert "no usable message on /separator/refined" in text
    assert replay.results == []


def test_bag_of_other_topics_is_foreign(tmp_path):
    store = typestore()
    with BagWriter(tmp_path / "bag") as writer:
        writer.write("/chatter", "std_msgs/msg/String", 1, store.types["std_msgs/msg/String"](data="hi"))
    replay = replay_bag(tmp_path / "bag")
    assert "a foreign bag: none of the pipeline's topics under namespace '/'" in str(replay.problems[0])
    assert "/chatter" in str(replay.problems[0]) and replay.results == []


def test_namespace_moves_the_topics(tmp_path):
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        class Prefixed:
            def write(self, topic, msgtype, timestamp, message):
                writer.write(topic if topic.startswith("/ground_truth") else "/robot1" + topic, msgtype,
                             timestamp, message)
        live = write_synthetic_run(bag, NEAR, writer=Prefixed())
    same_results(replay_bag(bag, config=ReplayConfig(namespace="/robot1")).results, live)
    assert replay_bag(bag).results == []


@pytest.mark.parametrize("make, match", [
    (lambda p: p.write_bytes(b"\x89MCAP0\r\n" + b"\x01" + (20).to_bytes(8, "little") + (8).to_bytes(4, "little")
                             + b"protobuf" + (4).to_bytes(4, "little") + b"test"), "profile 'protobuf', not 'ros2'"),
    (lambda p: p.write_bytes(b"SQLite format 3\x00" + bytes(100)), "is not an MCAP file"),
])
def test_foreign_files_raise(tmp_path, make, match):
    make(tmp_path / "x.mcap")
    with pytest.raises(BagError, match=match):
        replay_bag(tmp_path / "x.mcap")


def test_sqlite_storage_is_named(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: sqlite3\n  relative_file_paths: [bag_0.db3]\n")
    with pytest.raises(BagError, match="storage 'sqlite3' is not read here"):
        replay_bag(tmp_path / "bag")


@pytest.mark.parametrize("poisoned_step", [1, 4])
def test_nan_estimate_gives_up_that_episode_only(tmp_path, poisoned_step):
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        class Poison:
            def write(self, topic, msgtype, timestamp, message):
                if (topic == "/separator/refined" and message.episode_id.endswith("000000")
                        and message.step == poisoned_step):
                    message.data = np.full_like(message.data, np.nan)
                writer.write(topic, msgtype, timestamp, message)
        live = write_synthetic_run(bag, NEAR, writer=Poison())
    replay = replay_bag(bag)
    same_results(replay.results, live[1:])
    assert "NaN" in str(replay.problems[0]) and live[0].episode_id in str(replay.problems[0])
    # scored in other processes: the same outcome, named the same
    parallel = replay_bag(bag, config=ReplayConfig(score_processes=2))
    same_results(parallel.results, live[1:])
    assert [str(p) for p in parallel.problems] == [str(p) for p in replay.problems]


def test_cli_writes_tables_plots_and_exit_codes(near_bag, tmp_path, capsys):
    bag, live = near_bag
    assert m2h_eval([str(bag), "--out", str(tmp_path / "out")]) == 0
    out = tmp_path / "out"
    for name in ("results.md", "results.csv", "results.json", "comparison.md", "comparison.csv",
                 "si_sdr_vs_step.png", "si_sdr_vs_step_near_target_heard.png"):
        assert (out / name).is_file(), name
    document = json.loads((out / "results.json").read_text())
    assert [e["episode_id"] for e in document["episodes"]] == [r.episode_id for r in live]
    assert document["meta"]["bags"][0]["compared_steps"] == 15
    printed = capsys.readouterr().out
    assert "0 mismatch(es)" in printed and "SI-SDR (dB, GT phase)" in printed
    killed = killed_copy(bag, tmp_path / "killed", 0.5)
    assert m2h_eval([str(killed), "--out", str(tmp_path / "out2"), "--no-plots"]) == 3
    assert m2h_eval([str(tmp_path / "nope"), "--out", str(tmp_path / "out3")]) == 2
    assert m2h_eval([str(bag), "--out", str(tmp_path / "out4"), "--no-plots", "--workers", "1"]) == 0
    assert m2h_eval([str(bag), "--out", str(tmp_path / "out5"), "--workers", "0"]) == 2
    shutil.rmtree(killed)


def test_workers_replay_bags_in_processes_with_the_same_output(near_bag, tmp_path, capsys):
    bag, _ = near_bag
    far = tmp_path / "far"
    write_synthetic_run(far, SyntheticRun(episodes=2, max_steps=6, task="far_target", camera=False))
    killed = killed_copy(bag, tmp_path / "killed", 0.5)
    bags = [str(bag), str(tmp_path / "nope"), str(killed), str(far)]
    written = {}
    for workers in (1, 2):
        out = tmp_path / f"out{workers}"
        assert m2h_eval([*bags, "--out", str(out), "--no-plots", "--workers", str(workers)]) == 3
        captured = capsys.readouterr()
        written[workers] = [captured.out.replace(str(out), "OUT"), captured.err] + [
            (out / name).read_text() for name in ("results.csv", "results.json", "comparison.md", "comparison.csv")]
    assert written[1] == written[2]
    assert "nope" in written[1][1] and written[1][0].count(" step(s) scored") == 3
    assert m2h_eval([str(bag), "--out", str(tmp_path / "out3"), "--workers", "0"]) == 2
    shutil.rmtree(killed)


def test_one_bag_on_several_processes_writes_the_same_tables_as_one_process(tmp_path, capsys):
    """Read once here, its batches scored by child processes while reading goes on: the same tables,
    mismatches (in the same order) and printout as one process, estimates episodes late and all."""
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        class Tamper:  # live SI-SDRs off on odd steps: mismatches to list
            def write(self, topic, msgtype, timestamp, message):
                if topic == "/scores/step" and message.step % 2:
                    message.si_sdr += 0.5
                writer.write(topic, msgtype, timestamp, message)
        write_synthetic_run(bag, SyntheticRun(episodes=6, max_steps=4, camera=False, estimate_lag=7), writer=Tamper())
    written = {}
    for workers in (1, 2, 3):
        out = tmp_path / f"out{workers}"
        assert m2h_eval([str(bag), "--out", str(out), "--no-plots", "--workers", str(workers)]) == 1
        written[workers] = [capsys.readouterr().out.replace(str(out), "OUT")] + [
            (out / name).read_text() for name in ("results.csv", "results.json", "comparison.md", "comparison.csv")]
    assert written[1] == written[2] == written[3]
    assert written[1][4].count("\n") == 1 + 6 * 2  # the header and two odd steps of each of the 6 episodes


def test_a_damaged_first_chunk_costs_only_its_own_messages(tmp_path):
    """The first chunk declares the topics; the closed file's summary repeats the declarations, so the
    episodes after the damage are still read and scored."""
    bag = tmp_path / "bag"
    live = write_synthetic_run(bag, NEAR)
    mcap_file = next(bag.glob("*.mcap"))
    data = bytearray(mcap_file.read_bytes())
    first, second = chunk_offsets(data)[:2]
    data[(first + second) // 2] ^= 0xFF
    mcap_file.write_bytes(bytes(data))
    replay = replay_bag(bag)
    assert any(f"corrupt chunk 1 (bytes {first}-" in str(p) for p in replay.problems)
    assert not any("declaration was lost" in str(p) for p in replay.problems)
    assert live[-1].episode_id in {r.episode_id for r in replay.results}
    same_results([r for r in replay.results if r.episode_id == live[-1].episode_id], live[-1:])


def test_help_lists_the_exit_codes(capsys):
    with pytest.raises(SystemExit) as exited:
        m2h_eval(["--help"])
    assert exited.value.code == 0
    help_text = " ".join(capsys.readouterr().out.split())
    for code in ("0 all scored and equal to the live scores", "1 a live score differs beyond --atol",
                 "3 a bag is damaged or foreign", "2 bad options"):
        assert code in help_text
