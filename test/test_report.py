"""`report` on a synthetic lockstep recording gives what `compute_metrics` gives on the same data."""

from __future__ import annotations

import json
import math
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Transform
from nav_msgs.msg import Odometry, Path
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.params.files import read_parameter_file
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.offline.plots import FIGURE_SIZES_IN
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.bagfile import RUN_METADATA
from robotino_geom_mpc.recording.report import report_bag, run_data_from_bag
from robotino_geom_mpc.offline.results import RunData, compute_metrics, read_metrics

pytestmark = pytest.mark.ros

TS = 0.01
HORIZON = 4
N_TICKS = 300


def _quat(theta):
    return 0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)


def _stamp(msg, ns):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), 10**9)
    return msg


def _odom(ns, pose):
    msg = _stamp(Odometry(), ns)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.y = pose[0], pose[1]
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = _quat(pose[2])
    return msg


def _reference(t):
    return np.stack([0.5 * np.sin(t), 0.5 - 0.5 * np.cos(t), 1.5 * t], axis=-1)  # theta crosses pi


def _preview(ns):
    msg = _stamp(MultiDOFJointTrajectory(), ns)
    for j, (x, y, th) in enumerate(_reference(ns * 1e-9 + TS * np.arange(HORIZON + 1))):
        tf = Transform()
        tf.translation.x, tf.translation.y = float(x), float(y)
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = _quat(float(th))
        msg.points.append(MultiDOFJointTrajectoryPoint(transforms=[tf]))
    return msg


def _diag(ns, saturated, compute_ms):
    status = DiagnosticStatus(name="robotino_geom_mpc: controller", values=[
        KeyValue(key="error_x_m", value="0"), KeyValue(key="compute_time_ms", value=f"{compute_ms:.4f}"),
        KeyValue(key="saturated", value=str(saturated).lower()), KeyValue(key="infeasible", value="false")])
    return _stamp(DiagnosticArray(status=[status]), ns)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A lockstep recording written message by message, and the RunData it stands for."""
    rng = np.random.default_rng(7)
    t = TS * np.arange(N_TICKS)
    reference = _reference(t)
    pose = reference + rng.normal(0.0, 2e-3, size=reference.shape)
    currents = rng.uniform(-1.2, 1.2, size=(N_TICKS, 3))
    voltages = rng.uniform(-12.0, 12.0, size=(N_TICKS, 3))
    saturated = rng.random(N_TICKS) < 0.1
    compute_ms = np.round(rng.uniform(0.05, 0.3, size=N_TICKS), 4)
    values = read_parameter_file(default_params_file())
    values["motor.nominal_current_a"] = 0.9  # differs from the preset: the stored values must be used
    path = tmp_path_factory.mktemp("report") / "bag"
    with BagWriter(path) as bag:
        bag.add_metadata(RUN_METADATA, {"scenario": "synthetic-circle", "parameters": json.dumps(values)})
        ch = {name: bag.add_topic("/" + name, typ) for name, typ in [
            ("odom", "nav_msgs/msg/Odometry"), ("ground_truth/odom", "nav_msgs/msg/Odometry"),
            ("wheel_currents", "std_msgs/msg/Float64MultiArray"), ("wheel_voltages", "std_msgs/msg/Float64MultiArray"),
            ("reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory"),
            ("diagnostics", "diagnostic_msgs/msg/DiagnosticArray"), ("reference_path", "nav_msgs/msg/Path")]}
        path_msg = Path()
        for k, (x, y, th) in enumerate(reference):
            ps = _stamp(PoseStamped(), k * TS * 1e9)
            ps.pose.position.x, ps.pose.position.y = x, y
            path_msg.poses.append(ps)
        bag.write(ch["reference_path"], 1, serialize_message(path_msg), 1)

        def put(name, msg, publish):  # log time 50 us after the publish time, as a recorder would see it
            bag.write(ch[name], publish + 50_000, serialize_message(msg), publish)

        for k in range(N_TICKS):
            ns, base = int(round(k * TS * 1e9)), 10**9 + k * 10**6  # wall time of tick k: 1 ms per tick
            put("reference_preview", _preview(ns), base - 300_000)  # the trajectory runs one tick ahead
            put("odom", _odom(ns, pose[k] + 1e-4), base)
            put("ground_truth/odom", _odom(ns, pose[k]), base + 10_000)
            if k == N_TICKS - 1:
                break  # the recorder stopped before the controller answered the last tick
            if k == 100:  # the plant resends a tick: the same stamp again, counted once
                put("ground_truth/odom", _odom(ns, pose[k]), base + 100_000)
            put("wheel_voltages", Float64MultiArray(data=list(voltages[k])), base + 200_000)
            put("diagnostics", _diag(ns, saturated[k], compute_ms[k]), base + 210_000)
            # the plant integrates the period after tick k, then publishes its peak currents
            put("wheel_currents", Float64MultiArray(data=list(currents[k])), base + 500_000)
    n = N_TICKS - 1
    expected = RunData(
        scenario="synthetic-circle", t=t[:n], pose=pose[:n], reference=reference[:n], currents=currents[:n],
        voltages=voltages[:n], control_period_s=TS, horizon=HORIZON, nominal_current_a=0.9,
        supply_voltage_v=values["motor.supply_voltage_v"],
        flags={"saturated": saturated[:n], "infeasible": np.zeros(n, bool)}, compute_time_s=compute_ms[:n] * 1e-3,
        odometry=pose[:n] + 1e-4,  # the odom messages written above
    )
    return path, expected


def _assert_same_metrics(got: dict, want: dict) -> None:
    assert set(got) == set(want) | {"truth"} and got["truth"] == "ground_truth"  # a report names its truth
    for key, value in want.items():
        if isinstance(value, float):
            assert got[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        else:
            assert got[key] == value, key


def test_run_data_matches_the_recorded_series(synthetic):
    path, expected = synthetic
    run = run_data_from_bag(path)
    assert run.n == expected.n and run.scenario == expected.scenario
    np.testing.assert_allclose(run.t, expected.t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.pose, expected.pose, rtol=0, atol=1e-12)  # theta unwrapped past pi
    np.testing.assert_allclose(run.reference, expected.reference, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(run.currents, expected.currents)
    np.testing.assert_array_equal(run.voltages, expected.voltages)
    np.testing.assert_array_equal(run.flags["saturated"], expected.flags["saturated"])
    assert run.meta["ticks_dropped"] == 1


def test_report_gives_the_metrics_of_compute_metrics(synthetic, tmp_path):
    path, expected = synthetic
    metrics = report_bag(path, tmp_path / "out")
    _assert_same_metrics(metrics, compute_metrics(expected))
    _assert_same_metrics(read_metrics(tmp_path / "out" / "metrics.json"), compute_metrics(expected))
    assert {p.stem for p in (tmp_path / "out").glob("*.png")} == set(FIGURE_SIZES_IN)


def test_report_verb(synthetic, tmp_path, capsys):
    path, expected = synthetic
    mcap = next(path.glob("*.mcap"))  # a bare .mcap works too
    assert main(["report", str(mcap), "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    _assert_same_metrics(read_metrics(tmp_path / "o" / "metrics.json"), compute_metrics(expected))
    out = capsys.readouterr().out
    assert not list((tmp_path / "o").glob("*.png")) and f"wrote {tmp_path / 'o' / 'metrics.json'}" in out
    assert "truth: ground_truth" in out and read_metrics(tmp_path / "o" / "metrics.json")["truth"] == "ground_truth"
    assert main(["report", str(mcap), "--no-plots"]) == 0  # without --out: <bag>-report beside the bag
    beside = mcap.parent / f"{mcap.stem}-report" / "metrics.json"
    assert f"wrote {beside}" in capsys.readouterr().out
    _assert_same_metrics(read_metrics(beside), compute_metrics(expected))
    assert main(["report", str(tmp_path / "none"), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such bag" in err


def test_report_on_a_truncated_recording_names_the_damage_and_covers_what_was_read(synthetic, tmp_path, capsys):
    """A recorder killed mid-run: the report says so in one line and covers the ticks of the readable chunks."""
    import dataclasses

    from mcap.reader import make_reader

    from robotino_geom_mpc.recording.bag_reader import BagReader

    path, expected = synthetic
    source = BagReader(path)
    copy = tmp_path / "killed"
    with BagWriter(copy, chunk_size=16384) as out:  # small chunks, so a cut leaves several complete ones
        out.add_metadata(RUN_METADATA, source.metadata[RUN_METADATA])
        ch = {name: out.add_topic(name, info.type) for name, info in source.topics.items()}
        for m in source.messages():
            out.write(ch[m.topic], m.log_time_ns, m.data, m.publish_time_ns)
    mcap = copy / "killed_0.mcap"
    with open(mcap, "rb") as fh:
        reader = make_reader(fh)
        chunks = sorted(reader.get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
        kept = [m.log_time for _, _, m in reader.iter_messages()]  # mcap's own reader of the intact file
    assert len(chunks) > 4
    end = chunks[2].message_end_time  # cut inside the fourth chunk: three complete chunks remain
    mcap.write_bytes(mcap.read_bytes()[: chunks[3].chunk_start_offset + chunks[3].chunk_length // 2])
    (copy / "metadata.yaml").unlink()
    recovered = sum(t <= end for t in kept)
    # tick k is complete once its currents (logged 0.55 ms after the tick's 1 ms wall slot starts) are read
    ticks = sum(10**9 + k * 10**6 + 550_000 <= end for k in range(expected.n))

    assert main(["report", str(copy), "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "warning" in err and "is damaged" in err and "reindex" in err
    assert f"recovered {recovered} messages (" in err
    part = dataclasses.replace(expected, **{f: getattr(expected, f)[:ticks] for f in
                                            ("t", "pose", "reference", "currents", "voltages", "compute_time_s",
                                             "odometry")},
                               flags={k: v[:ticks] for k, v in expected.flags.items()})
    _assert_same_metrics(read_metrics(tmp_path / "o" / "metrics.json"), compute_metrics(part))


def _random_label(rng) -> str:
    return "".join(str(rng.choice(list("abc_xyz"))) for _ in range(int(rng.integers(0, 9))))


def _random_messages(rng):
    """Odometry, previews and Float64MultiArray with random values, string lengths (alignment) and counts."""
    for _ in range(40):
        q = rng.normal(size=4)
        odom = _stamp(Odometry(), int(rng.integers(0, 2**40)))
        odom.header.frame_id, odom.child_frame_id = _random_label(rng), _random_label(rng)
        p, o = odom.pose.pose.position, odom.pose.pose.orientation
        p.x, p.y, p.z = rng.normal(size=3)
        o.x, o.y, o.z, o.w = q / np.linalg.norm(q)
        odom.pose.covariance = rng.normal(size=36)
        yield "nav_msgs/msg/Odometry", odom
        preview = _stamp(MultiDOFJointTrajectory(), int(rng.integers(0, 2**40)))
        preview.header.frame_id = _random_label(rng)
        preview.joint_names = [_random_label(rng) for _ in range(int(rng.integers(0, 3)))]
        for _ in range(int(rng.integers(0, 3))):
            point = MultiDOFJointTrajectoryPoint()
            for _ in range(int(rng.integers(0, 3))):
                tf = Transform()
                tf.translation.x, tf.translation.y, tf.translation.z = rng.normal(size=3)
                tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = rng.normal(size=4)
                point.transforms.append(tf)
            preview.points.append(point)
        yield "trajectory_msgs/msg/MultiDOFJointTrajectory", preview
        values = Float64MultiArray(data=list(rng.normal(size=int(rng.integers(1, 5)))))  # rosbags refuses empty data
        for _ in range(int(rng.integers(0, 3))):
            dim = MultiArrayDimension(label=_random_label(rng), size=int(rng.integers(0, 9)),
                                      stride=int(rng.integers(0, 9)))
            values.layout.dim.append(dim)
        values.layout.data_offset = int(rng.integers(0, 5))
        yield "std_msgs/msg/Float64MultiArray", values
        diag = _stamp(DiagnosticArray(), int(rng.integers(0, 2**40)))
        for _ in range(int(rng.integers(0, 4))):
            status = DiagnosticStatus(level=bytes([int(rng.integers(0, 4))]), name=_random_label(rng),
                                      message=_random_label(rng) + "\u00b5", hardware_id=_random_label(rng))
            keys = [_random_label(rng) + "k" for _ in range(int(rng.integers(0, 4)))]
            if rng.random() < 0.4:
                keys.insert(int(rng.integers(0, len(keys) + 1)), "error_x_m")
            status.values = [KeyValue(key=k, value=_random_label(rng)) for k in keys]
            diag.status.append(status)
        yield "diagnostic_msgs/msg/DiagnosticArray", diag


def test_cdr_readers_read_what_the_decoders_decode():
    """The byte readers (`ros.cdr`) give, on rclpy's and rosbags' serializations of random messages, what they
    take from rosbags' decoded message; big-endian bytes (rosbags' serializer) go to the decoded message and give
    the same values.
    """
    from rosbags.typesys import Stores, get_typestore

    from robotino_geom_mpc.ros import cdr, decode

    readers = {"nav_msgs/msg/Odometry": (cdr.odometry_pose, decode.odometry_pose_of_message),
               "trajectory_msgs/msg/MultiDOFJointTrajectory": (cdr.preview_start, decode.preview_start_of_message),
               "std_msgs/msg/Float64MultiArray": (cdr.float64_array, decode.float64_array_of_message),
               "diagnostic_msgs/msg/DiagnosticArray": (cdr.diagnostics_with("error_x_m"),
                                                       decode.diagnostics_with_of_message("error_x_m"))}
    store = get_typestore(Stores.ROS2_JAZZY)
    seen = set()
    for type_name, msg in _random_messages(np.random.default_rng(7)):
        read, of_message = readers[type_name]
        data = serialize_message(msg)
        decoded = store.deserialize_cdr(data, type_name)
        expected = of_message(decoded)
        assert read(data) == expected, type_name
        assert read(bytes(store.serialize_cdr(decoded, type_name))) == expected, type_name  # a second writer
        big = store.serialize_cdr(decoded, type_name, little_endian=False)
        with pytest.raises(ValueError):
            read(big)
        assert cdr.values_of(big, read, of_message, lambda: store.deserialize_cdr(big, type_name)) == expected
        seen.add((type_name, expected[1] is None if type_name.startswith(("traj", "diag")) else len(expected)))
    for type_name in ("trajectory_msgs/msg/MultiDOFJointTrajectory", "diagnostic_msgs/msg/DiagnosticArray"):
        assert {(type_name, True), (type_name, False)} <= seen  # with and without the values looked for


def test_bag_reader_reads_the_messages_mcap_reads(synthetic):
    """BagReader's chunk walk gives mcap's own reader's messages (channel, times, sequence, bytes); a record
    running past its chunk's end is refused.
    """
    from mcap.reader import make_reader
    from mcap.records import Chunk

    from robotino_geom_mpc.recording.bag_reader import BagReader
    from robotino_geom_mpc.recording.bag_reader import _chunk_records

    path, _ = synthetic
    bag = BagReader(path)
    (file,) = sorted(path.glob("*.mcap"))
    with open(file, "rb") as stream:
        want = sorted((c.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data))
                      for _, c, m in make_reader(stream).iter_messages())
    got = sorted((m.topic, m.log_time_ns, m.publish_time_ns, m.sequence, m.data) for m in bag.messages())
    assert len(got) > 1500 and got == want
    record = bytes([0x05]) + (40).to_bytes(8, "little") + bytes(30)  # a message record 10 bytes short
    with pytest.raises(ValueError, match="past its end"):
        _chunk_records(Chunk(compression="", data=record, message_end_time=0,
                             message_start_time=0, uncompressed_crc=0, uncompressed_size=len(record)))
