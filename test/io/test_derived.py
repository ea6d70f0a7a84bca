"""What a bag gets beside the recorded topics: the TF tree from the odometry and the agent's pose, and
pcm-s16 RawAudio of the mixture, the separated estimate and the target."""

import numpy as np

from m2h_ros import topics
from m2h_ros.io.derived import PCM_GAIN, Derived
from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import typestore
from m2h_ros.io.synthetic import SyntheticRun, write_synthetic_run


def test_a_recorded_run_gets_its_tf_tree_and_audio_tracks(tmp_path):
    write_synthetic_run(tmp_path / "bag", SyntheticRun(episodes=2, max_steps=3, camera=False))
    store, derived = typestore(), Derived()
    recorded, extra = {}, {}
    for raw in BagStream(tmp_path / "bag").messages():
        recorded.setdefault(raw.topic, []).append(store.deserialize_cdr(raw.data, raw.msgtype))
        for topic, msgtype, data in derived.feed(raw.topic, raw.msgtype, raw.data):
            assert derived.topics()[topic] == msgtype
            extra.setdefault(topic, []).append(store.deserialize_cdr(data, msgtype))
    (static,) = extra["/tf_static"]
    parents = {t.child_frame_id: t.header.frame_id for t in static.transforms}
    assert parents == {"odom": "map", "head": "base_link", "camera": "head"}
    assert len(extra["/tf"]) == len(recorded["/" + topics.ODOM])
    for tf, odom in zip(extra["/tf"], recorded["/" + topics.ODOM], strict=True):
        (t,) = tf.transforms
        assert (t.header.frame_id, t.child_frame_id, t.header.stamp) == ("odom", "base_link", odom.header.stamp)
        assert (t.transform.translation.x, t.transform.translation.y) == (odom.pose.pose.position.x,
                                                                          odom.pose.pose.position.y)
        assert t.transform.rotation.z == odom.pose.pose.orientation.z
    for source, field, channels in (("/" + topics.AUDIO, "samples", 2), ("/" + topics.SEPARATED_AUDIO, "samples", 1),
                                    (topics.GROUND_TRUTH, "target_monaural", 1)):
        tracks = extra[source + "/pcm"]
        assert len(tracks) == len(recorded[source])
        for audio, original in zip(tracks, recorded[source], strict=True):
            assert (audio.format, audio.sample_rate, audio.number_of_channels) == ("pcm-s16", 16000, channels)
            assert audio.timestamp == original.header.stamp
            heard = np.frombuffer(audio.data.tobytes(), "<i2").reshape(-1, channels).T / (32767 * PCM_GAIN)
            samples = np.asarray(getattr(original, field)).reshape(channels, -1)
            np.testing.assert_allclose(heard, np.clip(samples, -1 / PCM_GAIN, 1 / PCM_GAIN), atol=1 / (32767 * PCM_GAIN))
