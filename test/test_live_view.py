"""`run --foxglove PORT`: a Foxglove WebSocket client sees the run's topics live, the same messages as the bag.

The client speaks the protocol itself (`websockets`; subprotocol ``foxglove.sdk.v1``, which the SDK's server
accepts, offered beside the older name ``foxglove.websocket.v1``): it waits for the ``advertise`` of /odom, /tf and
/robot_description, subscribes them, and collects the binary message-data frames (opcode 1, subscription id,
log time, payload) until the server closes at the run's end. The payloads are decoded by rosbags (an independent
CDR reader) and compared with the run's bag read by the mcap library: every live sample is a recorded one, the
same stamps and values, byte for byte the same CDR; the advertised schema is the bag's.

The SDK (0.30, and its main branch in 2026-11) sends a channel's ``advertise`` before it registers the channel
for the client (rust/foxglove/src/websocket/connected_client.rs, ``advertise_channels``: send, then insert), so a
client that subscribes at once can get ``Unknown channel ID`` (a loaded CI host: no /odom at all); the client
here subscribes again after such a refusal, as a client has to.
"""

import pytest
import asyncio
import json
import os
import socket
import struct
import subprocess
import sys
import time

import websockets
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore

pytestmark = pytest.mark.ros

TOPICS = ("/odom", "/tf", "/robot_description")
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
DURATION_S = 6.0
CONNECT_TIMEOUT_S = 120.0
UNKNOWN_CHANNEL = "Unknown channel ID: "  # the SDK's error status for a subscription it refuses
RESUBSCRIBE_S = 0.05


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


async def _watch(port: int, proc: subprocess.Popen) -> tuple[dict, dict]:
    """Connect, subscribe `TOPICS`, collect payloads per topic until the server closes; (channels, payloads)."""
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None)
            break
        except OSError:
            assert proc.poll() is None and time.monotonic() < deadline, "the live view never served"
            await asyncio.sleep(0.1)
    channels, subscriptions, payloads = {}, {}, {topic: [] for topic in TOPICS}
    async with ws:
        assert ws.subprotocol in SUBPROTOCOLS
        try:
            async for frame in ws:
                if isinstance(frame, str):
                    message = json.loads(frame)
                    refused = message["op"] == "status" and message["message"].startswith(UNKNOWN_CHANNEL)
                    if refused:  # the SDK's race (module docstring): subscribe again once it has the channel
                        channel_id = int(message["message"].removeprefix(UNKNOWN_CHANNEL))
                        sub_id = next(i for i, topic in subscriptions.items() if channels[topic]["id"] == channel_id)
                        await asyncio.sleep(RESUBSCRIBE_S)
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": sub_id, "channelId": channel_id}]}))
                    if message["op"] != "advertise":
                        continue
                    for channel in message["channels"]:
                        if channel["topic"] in TOPICS and channel["topic"] not in channels:
                            channels[channel["topic"]] = channel
                            sub_id = len(subscriptions) + 1
                            subscriptions[sub_id] = channel["topic"]
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                {"id": sub_id, "channelId": channel["id"]}]}))
                elif frame[0] == 1:  # message data: opcode, subscription id, log time [ns], payload
                    _, sub_id, _ = struct.unpack_from("<BIQ", frame)
                    payloads[subscriptions[sub_id]].append(bytes(frame[13:]))
        except websockets.ConnectionClosed:
            pass
    return channels, payloads


def _bag(bag_dir):
    """The bag's schemas (topic -> definition text) and raw samples (topic -> list of CDR bytes), via mcap."""
    schemas, samples = {}, {topic: [] for topic in TOPICS}
    for path in sorted(bag_dir.glob("*.mcap")):
        with open(path, "rb") as f:
            for schema, channel, message in make_reader(f).iter_messages(topics=TOPICS):
                schemas[channel.topic] = (schema.name, schema.encoding, schema.data.decode())
                samples[channel.topic].append(bytes(message.data))
    return schemas, samples


def _odom_values(msg) -> tuple:
    pose, twist = msg.pose.pose, msg.twist.twist
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id, msg.child_frame_id,
            pose.position.x, pose.position.y, pose.orientation.z, pose.orientation.w,
            twist.linear.x, twist.linear.y, twist.angular.z)


def _tf_values(msg) -> tuple:
    return tuple((t.header.stamp.sec, t.header.stamp.nanosec, t.header.frame_id, t.child_frame_id,
                  t.transform.translation.x, t.transform.translation.y, t.transform.rotation.z,
                  t.transform.rotation.w) for t in msg.transforms)


@pytest.mark.slow
def test_run_foxglove_serves_the_recorded_messages_live(tmp_path):
    port, out = _free_port(), tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "paper-circle",
                             "--realtime", "--duration", str(DURATION_S), "--foxglove", str(port), "--out", str(out),
                             "--no-plots"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy())
    try:
        channels, live = asyncio.run(asyncio.wait_for(_watch(port, proc), 300))
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr + stdout
    assert f"ws://localhost:{port}" in stdout

    schemas, recorded = _bag(out / "bag")
    store = get_typestore(Stores.ROS2_JAZZY)
    for topic, channel in channels.items():  # the schema the bag stores, as ros2msg over cdr
        assert (channel["schemaName"], channel["schemaEncoding"], channel["schema"]) == schemas[topic]
        assert channel["encoding"] == "cdr"
    assert set(channels) == set(TOPICS)
    # a realtime run of 6 s: 600 odometry ticks; `run` starts the loop once the view serves, the client is on by then
    assert len(live["/odom"]) > 100 and len(live["/tf"]) > 100
    for topic, values, type_name in (("/odom", _odom_values, "nav_msgs/msg/Odometry"),
                                     ("/tf", _tf_values, "tf2_msgs/msg/TFMessage")):
        in_bag = {values(store.deserialize_cdr(data, type_name)): data for data in recorded[topic]}
        stamp = (lambda key: key[:2]) if topic == "/odom" else (lambda key: key[0][:2])
        # /tf has two writers (the plant's odom -> base_link, the wheels' transforms), which the recorder matches
        # one by one: the first sample in the bag per writer (its frames)
        writer = (lambda key: key[2:4]) if topic == "/odom" else (lambda key: tuple(t[2:4] for t in key))
        first: dict = {}
        for key in in_bag:
            first[writer(key)] = min(first.get(writer(key), stamp(key)), stamp(key))
        live_keys = [values(store.deserialize_cdr(data, type_name)) for data in live[topic]]
        assert set(first) == {writer(key) for key in live_keys}  # every writer seen live is in the bag
        for data, key in zip(live[topic], live_keys):
            if stamp(key) < first[writer(key)]:
                continue  # sent before the recorder matched its writer (a realtime run does not wait for it)
            assert key in in_bag, f"{topic}: a live sample not in the bag: {key}"
            assert data == in_bag[key]  # forwarded as published: no re-encoding
        assert len({values(store.deserialize_cdr(d, type_name)) for d in live[topic]}) == len(live[topic])
    stamps = [store.deserialize_cdr(d, "nav_msgs/msg/Odometry").header.stamp for d in live["/odom"]]
    ns = [s.sec * 10**9 + s.nanosec for s in stamps]
    assert ns == sorted(ns)  # in order, as published
    # the URDF, latched, reaches the client that subscribed after it was published
    urdf = store.deserialize_cdr(live["/robot_description"][0], "std_msgs/msg/String").data
    assert urdf == store.deserialize_cdr(recorded["/robot_description"][0], "std_msgs/msg/String").data
    assert "<robot" in urdf


def test_a_lockstep_run_with_the_live_view_waits_for_it_and_goes_at_real_time():
    """node_arguments: the live view's node and port; the lockstep plant waits for one more subscription on each
    topic (the view subscribes every topic, so the recorder's still count) and is paced at real time at most.
    """
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import node_arguments, recorder_wait_for

    plain = node_arguments("paper-circle", default_params_file(), 3.0, True, bag="/tmp/bag")
    viewed = node_arguments("paper-circle", default_params_file(), 3.0, True, bag="/tmp/bag", live_view_port=8770)
    assert set(viewed) == set(plain) | {"live_view_node"}
    assert "port:=8770" in viewed["live_view_node"]

    def plant_parameter(args, name):
        values = [a.split(":=", 1)[1] for a in args["plant_node"] if a.startswith(f"{name}:=")]
        return values[-1] if values else None

    wanted = [f"{topic}:{int(count) + 1}" for topic, _, count in (w.rpartition(":") for w in recorder_wait_for())]
    assert plant_parameter(viewed, "lockstep_wait_for") == "[" + ",".join(f'"{w}"' for w in wanted) + "]"
    assert plant_parameter(viewed, "lockstep_max_realtime_factor") == "1.0"
    assert plant_parameter(plain, "lockstep_max_realtime_factor") is None
    realtime = node_arguments("paper-circle", default_params_file(), 3.0, False, live_view_port=8770)
    assert plant_parameter(realtime, "lockstep_max_realtime_factor") is None


def test_a_run_whose_live_view_cannot_serve_fails_before_the_loop_starts(tmp_path):
    """The port is taken: `run` reports the live view's own error, exit status 1, and started no other node."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "paper-circle",
                               "--realtime", "--duration", "2", "--foxglove", str(port), "--out", str(tmp_path)],
                              capture_output=True, text=True, env=os.environ.copy(), timeout=120)
    assert proc.returncode == 1, proc.stderr + proc.stdout
    assert "live_view_node exited with status" in proc.stderr and f"cannot serve on 127.0.0.1:{port}" in proc.stderr
    assert sorted(p.name for p in (tmp_path / "logs").iterdir()) == ["live_view_node.err.log", "live_view_node.out.log"]
