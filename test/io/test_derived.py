"""What a bag gets beside the recorded topics: the TF tree from the odometry and the agent's pose, and
pcm-s16 RawAudio of the mixture, the separated estimate and the target; the path as markers."""

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic
from rotations import rotation_matrix

from m2h_ros import topics
from m2h_ros.io.derived import PCM_GAIN, Derived, path_markers_cdr
from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import typestore
from m2h_ros.io.synthetic import SyntheticRun, write_synthetic_run


def _vector(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z])


def _matrix(q) -> np.ndarray:
    return rotation_matrix(q.x, q.y, q.z, q.w)


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
    # The static frames in full: map = odom, the head at the ears' height above the base, the camera's
    # optical frame looking along the body's x with its x to the right and its y down.
    height = recorded["/" + topics.AGENT_POSE][0].pose.position.z
    static_at = {t.child_frame_id: (_vector(t.transform.translation), _matrix(t.transform.rotation))
                 for t in static.transforms}
    assert all(t.header.stamp == recorded["/" + topics.AGENT_POSE][0].header.stamp for t in static.transforms)
    np.testing.assert_array_equal(static_at["odom"][0], [0, 0, 0])
    np.testing.assert_array_equal(static_at["head"][0], [0, 0, height])
    np.testing.assert_array_equal(static_at["camera"][0], [0, 0, 0])  # the camera at the ears
    for child in ("odom", "head"):
        np.testing.assert_allclose(static_at[child][1], np.eye(3), atol=1e-12)
    optical = static_at["camera"][1]
    np.testing.assert_allclose(optical @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # optical z: forward
    np.testing.assert_allclose(optical @ [1, 0, 0], [0, -1, 0], atol=1e-12)  # optical x: right
    np.testing.assert_allclose(optical @ [0, 1, 0], [0, 0, -1], atol=1e-12)  # optical y: down
    # Each step's odom -> base_link is the odometry's pose whole: position on the floor and the full
    # rotation, the base's x axis along the robot's heading.
    assert len(extra["/tf"]) == len(recorded["/" + topics.ODOM])
    headings = set()
    for tf, odom in zip(extra["/tf"], recorded["/" + topics.ODOM], strict=True):
        (t,) = tf.transforms
        assert (t.header.frame_id, t.child_frame_id, t.header.stamp) == ("odom", "base_link", odom.header.stamp)
        position, orientation = odom.pose.pose.position, odom.pose.pose.orientation
        np.testing.assert_array_equal(_vector(t.transform.translation), [position.x, position.y, 0.0])
        q = t.transform.rotation
        assert (q.x, q.y, q.z, q.w) == pytest.approx((orientation.x, orientation.y, orientation.z, orientation.w),
                                                     abs=1e-12) or (q.x, q.y, q.z, q.w) == pytest.approx(
            (-orientation.x, -orientation.y, -orientation.z, -orientation.w), abs=1e-12)  # q and -q: one rotation
        assert q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2 == pytest.approx(1.0)
        np.testing.assert_allclose(_matrix(q), _matrix(orientation), atol=1e-12)
        forward = _matrix(q) @ [1, 0, 0]
        headings.add(round(float(np.degrees(np.arctan2(forward[1], forward[0]))) % 360))
    assert len(headings) > 1  # the synthetic robot turns: more than one heading checked
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


def test_the_path_decodes_with_an_independent_reader_as_a_line_and_dots_through_every_position():
    store = typestore()
    decode = generate_dynamic("visualization_msgs/msg/MarkerArray",
                              store.generate_msgdef("visualization_msgs/msg/MarkerArray", ros_version=2)[0])
    decode = decode["visualization_msgs/msg/MarkerArray"]
    for positions in (np.array([[1.0, 2.0]]), np.array([[0.0, 0.5], [1.5, -2.0], [3.25, 4.0]])):
        stamp = 12 * 10**9 + 345
        markers = decode(path_markers_cdr(positions, height=1.25, stamp_ns=stamp)).markers
        assert [(m.ns, m.id, m.type, m.action) for m in markers] == [("path", 0, 4, 0), ("path", 1, 7, 0)]
        for marker in markers:
            assert marker.header.frame_id == "map"
            assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (12, 345)
            assert [(p.x, p.y, p.z) for p in marker.points] == [(x, y, 1.25) for x, y in positions]
            q = marker.pose.orientation
            assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
            assert marker.color.a == pytest.approx(1.0) and marker.color.b == pytest.approx(0.9)
            assert marker.text == "" and list(marker.colors) == []
        assert markers[0].scale.x == pytest.approx(0.05) and markers[1].scale.z == pytest.approx(0.15)


def test_a_clip_repeated_from_step_to_step_gives_what_a_fresh_conversion_gives(tmp_path):
    """The target's dry clip is the same at every step of an episode and is converted once: each step's
    picture and track still equal a fresh conversion of its own message, the next episode's clip too."""
    from m2h_ros.core.audio.pcm import pcm_int16
    from m2h_ros.core.audio.stft import stft
    from m2h_ros.io.derived import spectrogram_image_cdr

    write_synthetic_run(tmp_path / "bag", SyntheticRun(episodes=2, max_steps=3, camera=False))
    store, derived = typestore(), Derived(views=True)
    pictures, tracks, clips = [], [], []
    for raw in BagStream(tmp_path / "bag").messages():
        made = {topic: data for topic, _, data in derived.feed(raw.topic, raw.msgtype, raw.data)}
        if raw.topic != topics.GROUND_TRUTH:
            continue
        truth = store.deserialize_cdr(raw.data, raw.msgtype)
        stamp = truth.header.stamp.sec * 10**9 + truth.header.stamp.nanosec
        clip = np.asarray(truth.target_monaural, np.float32)
        clips.append(clip)
        assert made[topics.TARGET_IMAGE] == spectrogram_image_cdr(np.abs(stft(clip)), stamp_ns=stamp)
        pictures.append(made[topics.TARGET_IMAGE])
        track = store.deserialize_cdr(made[topics.GROUND_TRUTH + "/pcm"], "foxglove_msgs/msg/RawAudio")
        assert track.data.tobytes() == pcm_int16(clip, gain=PCM_GAIN) and track.timestamp == truth.header.stamp
        tracks.append(track)
    assert len(clips) == 8 and np.array_equal(clips[0], clips[3]) and not np.array_equal(clips[3], clips[4])
    assert len(set(pictures)) == 8  # each stamped with its own step
