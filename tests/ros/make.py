#!/usr/bin/env python3
"""Writes the ROS bag fixtures the tests read, with an independent writer (the `rosbags`
package, 0.11): small bags in every storage and compression dynacal reads, and the figures
`rosbags` reads from the shared real bags (`../shared/data/ros-bags/`). Values are exact
binary fractions (k / 1024 and the like) so a test can recompute every one. Run once; the
files are committed.

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install rosbags==0.11.9 numpy
    /tmp/venv/bin/python tests/ros/make.py [DYNACAL_DATA]

Topics of every written bag (header stamps from T0 = 1 700 000 000 s):
- `/imu/data` (sensor_msgs/Imu, frame `imu_link`): 64 messages, stamp T0 + k/128 s; angular
  velocity ((k*3 % 17) - 8) / 1024, ((k*5 % 17) - 8) / 1024, ((k*7 % 17) - 8) / 1024 rad/s
  (ROS forward-left-up); linear acceleration ((k*11 % 17) - 8) / 256 + (0, 0, 9.8125) m/s^2;
  covariance diagonals 2^-20 and 2^-14, orientation covariance -1 (no orientation).
- `/imu/messy` (sensor_msgs/Imu, frame `imu_messy`): 40 messages on the same grid, but
  message 10 repeats message 9's stamp, message 20's goes back 1/256 s before message 19's,
  and message 30's header stamp is zero (its receive time is the grid time); covariances 0.
- `/odom_imu/imu` (sensor_msgs/Imu): 20 messages whose rates and accelerations are all zero.
- `/gps/fix` (sensor_msgs/NavSatFix): 5 fixes at 1 Hz, latitude 46.5 + k/1024 deg, longitude
  6.5 - k/2048 deg, altitude 400 + k m; fix 3 has status -1 (no fix).
- `/odom` (nav_msgs/Odometry): 5 messages at 4 Hz, yaw k/8 rad about up, body velocity
  (k + 1, 0.5, -0.25) m/s forward-left-up.
The receive time of each message is its grid time plus 1/1024 s.
It also writes damaged copies into `tests/bad-input/` (`ros1-*.bag`, `mcap-truncated.mcap`,
`db3-truncated.db3`).
"""
import json
import os
import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_typestore

HERE = Path(os.path.dirname(os.path.abspath(__file__)))
T0 = 1_700_000_000
NS = 1_000_000_000


def stamp(store, t_ns):
    Time = store.types["builtin_interfaces/msg/Time"]
    return Time(sec=t_ns // NS, nanosec=t_ns % NS)


def header(store, t_ns, frame):
    Header = store.types["std_msgs/msg/Header"]
    if "seq" in Header.__dataclass_fields__:  # ROS1's header counts its messages
        return Header(seq=0, stamp=stamp(store, t_ns), frame_id=frame)
    return Header(stamp=stamp(store, t_ns), frame_id=frame)


def imu(store, t_ns, frame, gyro, accel, gyro_var, accel_var):
    T = store.types
    return T["sensor_msgs/msg/Imu"](
        header=header(store, t_ns, frame),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.array([-1.0] + [0.0] * 8),
        angular_velocity=T["geometry_msgs/msg/Vector3"](x=gyro[0], y=gyro[1], z=gyro[2]),
        angular_velocity_covariance=np.diag([gyro_var] * 3).flatten(),
        linear_acceleration=T["geometry_msgs/msg/Vector3"](x=accel[0], y=accel[1], z=accel[2]),
        linear_acceleration_covariance=np.diag([accel_var] * 3).flatten(),
    )


def grid_ns(k, hz=128):
    return T0 * NS + k * NS // hz


def messages(store):
    """(topic, msgtype, receive time ns, message) in receive order."""
    T = store.types
    out = []
    for k in range(64):
        g = [((k * m % 17) - 8) / 1024 for m in (3, 5, 7)]
        a = [((k * 11 % 17) - 8) / 256, 0.0, 9.8125]
        msg = imu(store, grid_ns(k), "imu_link", g, a, 2.0**-20, 2.0**-14)
        out.append(("/imu/data", "sensor_msgs/msg/Imu", grid_ns(k) + NS // 1024, msg))
    for k in range(40):
        t = grid_ns(k)
        if k == 10:
            t = grid_ns(9)
        if k == 20:
            t = grid_ns(19) - NS // 256
        if k == 30:
            t = 0
        g = [k / 512, -k / 1024, 0.25]
        a = [0.5, -k / 256, 9.75]
        msg = imu(store, t, "imu_messy", g, a, 0.0, 0.0)
        out.append(("/imu/messy", "sensor_msgs/msg/Imu", grid_ns(k) + NS // 1024, msg))
    for k in range(20):
        msg = imu(store, grid_ns(k), "ref_imu", [0.0] * 3, [0.0] * 3, 0.0, 0.0)
        out.append(("/odom_imu/imu", "sensor_msgs/msg/Imu", grid_ns(k) + NS // 1024, msg))
    for k in range(5):
        t = grid_ns(k, 1)
        status = T["sensor_msgs/msg/NavSatStatus"](status=-1 if k == 3 else 0, service=1)
        fix = T["sensor_msgs/msg/NavSatFix"](
            header=header(store, t, "gps"),
            status=status,
            latitude=46.5 + k / 1024,
            longitude=6.5 - k / 2048,
            altitude=400.0 + k,
            position_covariance=np.diag([4.0, 4.0, 16.0]).flatten(),
            position_covariance_type=2,
        )
        out.append(("/gps/fix", "sensor_msgs/msg/NavSatFix", t + NS // 1024, fix))
    for k in range(5):
        t = grid_ns(k, 4)
        yaw = k / 8
        q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2))
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=float(k), y=0.0, z=0.0), orientation=q
        )
        twist = T["geometry_msgs/msg/Twist"](
            linear=T["geometry_msgs/msg/Vector3"](x=k + 1.0, y=0.5, z=-0.25),
            angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.125),
        )
        odom = T["nav_msgs/msg/Odometry"](
            header=header(store, t, "odom"),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )
        out.append(("/odom", "nav_msgs/msg/Odometry", t + NS // 1024, odom))
    out.sort(key=lambda m: m[2])
    return out


def write_ros1(path, compression):
    store = get_typestore(Stores.ROS1_NOETIC)
    path.unlink(missing_ok=True)
    w = Writer1(path)
    if compression:
        w.set_compression(getattr(Writer1.CompressionFormat, compression))
    w.open()
    conns = {}
    for topic, msgtype, t, msg in messages(store):
        if topic not in conns:
            conns[topic] = w.add_connection(topic, msgtype, typestore=store)
        w.write(conns[topic], t, store.serialize_ros1(msg, msgtype))
    w.close()


def write_ros2(path, storage, compression=None):
    store = get_typestore(Stores.ROS2_HUMBLE)
    if path.exists():
        for f in path.iterdir():
            f.unlink()
        path.rmdir()
    w = Writer2(path, version=9, storage_plugin=storage)
    if compression:
        w.set_compression(getattr(CompressionMode, compression), CompressionFormat.ZSTD)
    w.open()
    conns = {}
    for topic, msgtype, t, msg in messages(store):
        if topic not in conns:
            conns[topic] = w.add_connection(topic, msgtype, typestore=store)
        w.write(conns[topic], t, store.serialize_cdr(msg, msgtype))
    w.close()


def real_bag_figures(data):
    """What `rosbags` reads from the shared bags: per topic type and count; per Imu topic
    the header stamps, frame, and per-axis mean and standard deviation as stored (ROS
    forward-left-up)."""
    from rosbags.highlevel import AnyReader

    figures = {}
    for name in ["xsens-test1.bag", "xsens-test1-mcap"]:
        with AnyReader([data / "ros-bags" / name]) as reader:
            topics = {}
            for c in reader.connections:
                entry = {"type": c.msgtype, "count": c.msgcount}
                if c.msgtype == "sensor_msgs/msg/Imu":
                    stamps, gyro, accel, frames = [], [], [], set()
                    for con, _, raw in reader.messages(connections=[c]):
                        m = reader.deserialize(raw, con.msgtype)
                        stamps.append(m.header.stamp.sec * NS + m.header.stamp.nanosec)
                        v, a = m.angular_velocity, m.linear_acceleration
                        gyro.append([v.x, v.y, v.z])
                        accel.append([a.x, a.y, a.z])
                        frames.add(m.header.frame_id)
                    stamps = np.array(stamps)
                    d = np.diff(stamps)
                    gyro, accel = np.array(gyro), np.array(accel)
                    entry.update(
                        first_stamp_ns=int(stamps[0]),
                        last_stamp_ns=int(stamps[-1]),
                        max_stamp_ns=int(stamps.max()),
                        repeated=int((d == 0).sum()),
                        back=int((d < 0).sum()),
                        frames=sorted(frames),
                        gyro_mean=gyro.mean(0).tolist(),
                        gyro_std=gyro.std(0, ddof=1).tolist(),
                        accel_mean=accel.mean(0).tolist(),
                        accel_std=accel.std(0, ddof=1).tolist(),
                    )
                topics[c.topic] = entry
            figures[name] = topics
    return figures


def broken_bags(out, bad):
    """Damaged copies of the written bags for the bad-input corpus (`tests/bad-input`)."""
    bag = (out / "ros1-bz2.bag").read_bytes()
    (bad / "ros1-truncated.bag").write_bytes(bag[: len(bag) // 2])
    chunk = bytearray(bag)
    at = chunk.find(b"BZh") + 200  # inside the first chunk's bz2 stream
    chunk[at] ^= 0xFF
    chunk[at + 1] ^= 0x55
    (bad / "ros1-chunk-corrupt.bag").write_bytes(bytes(chunk))
    (bad / "ros1-unknown-compression.bag").write_bytes(
        bag.replace(b"compression=bz2", b"compression=xz2", 1)
    )
    mcap = (out / "ros2-mcap" / "ros2-mcap.mcap").read_bytes()
    (bad / "mcap-truncated.mcap").write_bytes(mcap[: len(mcap) // 2])
    db3 = (out / "ros2-sqlite3" / "ros2-sqlite3.db3").read_bytes()
    (bad / "db3-truncated.db3").write_bytes(db3[: len(db3) // 2])


def main():
    out = HERE
    write_ros1(out / "ros1-plain.bag", None)
    write_ros1(out / "ros1-bz2.bag", "BZ2")
    write_ros1(out / "ros1-lz4.bag", "LZ4")
    write_ros2(out / "ros2-mcap", StoragePlugin.MCAP)
    write_ros2(out / "ros2-sqlite3", StoragePlugin.SQLITE3)
    write_ros2(out / "ros2-mcap-zstd-message", StoragePlugin.MCAP, "MESSAGE")
    write_ros2(out / "ros2-sqlite3-zstd-file", StoragePlugin.SQLITE3, "FILE")
    broken_bags(out, HERE.parent / "bad-input")
    data = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("DYNACAL_DATA", HERE / "../../../shared/data"))
    with open(out / "real-bags.json", "w") as f:
        json.dump(real_bag_figures(data), f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
