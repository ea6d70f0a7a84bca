"""m2h-derive: a bag recorded without its derived topics gets every one of them, each message equal to what
the node would have published, and keeps its own messages as they were."""

import numpy as np
import pytest

from m2h_ros import topics
from m2h_ros.core.audio.display import spectrogram_image
from m2h_ros.core.audio.stft import stft
from m2h_ros.derive_cli import main
from m2h_ros.errors import BagError
from m2h_ros.io.derive_bag import derive_bag
from m2h_ros.io.derived import derived_topics
from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import typestore
from m2h_ros.io.synthetic import SyntheticRun, write_synthetic_run


def raw(bag) -> list[tuple[str, int, bytes]]:
    return [(m.topic, m.log_time, bytes(m.data)) for m in BagStream(bag).messages()]


def picture(message) -> np.ndarray:
    return np.frombuffer(message.data.tobytes(), "<f4").reshape(message.height, message.width)


@pytest.fixture
def bag(tmp_path):
    path = tmp_path / "bag"
    write_synthetic_run(path, SyntheticRun(episodes=2, max_steps=3, camera=False))
    return path


def test_a_bag_gets_every_derived_topic_beside_its_own_messages(bag):
    before = raw(bag)
    result = derive_bag(bag)
    after = raw(bag)
    assert set(result.added) == set(derived_topics())
    assert [m for m in after if m[0] not in result.added] == before  # kept: order, times, bytes
    store, types = typestore(), _types(bag)
    messages: dict[str, list] = {}
    for topic, _, data in after:
        messages.setdefault(topic, []).append(store.deserialize_cdr(data, types[topic]))
    steps = len(messages["/" + topics.AUDIO])
    assert all(count == (1 if topic == topics.TF_STATIC else steps) for topic, count in result.added.items())
    # The pictures: what the separator and the evaluator build from the same arrays.
    for audio, image in zip(messages["/" + topics.AUDIO], messages["/" + topics.MIXTURE_IMAGE], strict=True):
        mixture = np.asarray(audio.samples, np.float32).reshape(2, -1)
        np.testing.assert_array_equal(picture(image), spectrogram_image(np.abs(stft(mixture))))
        assert (image.header.stamp, image.header.frame_id, image.encoding) == (audio.header.stamp, "head", "32FC1")
    for truth, image in zip(messages[topics.GROUND_TRUTH], messages[topics.TARGET_IMAGE], strict=True):
        np.testing.assert_array_equal(picture(image), spectrogram_image(np.abs(stft(
            np.asarray(truth.target_monaural, np.float32)))))
    for source, shown in ((topics.SEPARATED_BINAURAL, topics.BINAURAL_IMAGE), (topics.REFINED, topics.REFINED_IMAGE)):
        for spectrogram, image in zip(messages["/" + source], messages["/" + shown], strict=True):
            values = np.asarray(spectrogram.data, np.float32).reshape(tuple(spectrogram.shape))
            np.testing.assert_array_equal(picture(image), spectrogram_image(values))
    # The path: every position of the episode so far, restarting with each episode.
    poses = messages["/" + topics.AGENT_POSE]
    for k, (pose, path) in enumerate(zip(poses, messages["/" + topics.PATH], strict=True)):
        episode = [p for p in poses[:k + 1] if p.episode_id == pose.episode_id]
        line, dots = path.markers
        expected = [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in episode]
        assert [(q.x, q.y, q.z) for q in line.points] == [(q.x, q.y, q.z) for q in dots.points] == expected
        assert (line.header.frame_id, line.header.stamp) == ("map", pose.header.stamp)


def _types(bag) -> dict[str, str]:
    stream = BagStream(bag)
    for _ in stream.messages():
        pass
    return {topic: channel.msgtype for topic, channel in stream.channels.items()}


def test_a_bag_that_has_them_is_left_untouched_and_out_writes_a_new_one(bag, tmp_path):
    copy = tmp_path / "derived"
    before = raw(bag)
    assert derive_bag(bag, out=copy).added
    assert raw(bag) == before  # --out leaves the original as it was
    mcap = next(copy.glob("*.mcap"))
    stamp = mcap.stat().st_mtime_ns
    again = derive_bag(copy)
    assert not again.added and "nothing to add" in again.summary
    assert mcap.stat().st_mtime_ns == stamp
    with pytest.raises(BagError, match="already exists"):
        derive_bag(bag, out=copy)


def test_m2h_derive_names_a_bag_it_cannot_read(tmp_path, capsys):
    assert main([str(tmp_path / "missing")]) == 2
    assert f"m2h-derive: error: bag {tmp_path / 'missing'} does not exist" in capsys.readouterr().err
