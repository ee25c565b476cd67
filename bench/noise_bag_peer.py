"""The Python pipeline people run from a ROS bag to Kalibr's imu.yaml, as the peer of
`dynacal noise BAG --topic T --kalibr imu.yaml` for speed and memory (BENCHMARKS.md,
"Against the peers"): the `rosbags` package reads the topic's messages, `allantools`
computes each axis' overlapping Allan deviation at octave averaging times, and the slope
lines of `allan_variance_ros`'s analysis give N (the -1/2 line through tau <= 10 s, read at
1 s) and K (the +1/2 line through tau >= 100 s, read at 3 s); the yaml takes the mean of
the three axes' squares, as dynacal's export does.

Usage: noise_bag_peer.py BAG TOPIC OUT.yaml
"""
import sys
import time
from pathlib import Path

import allantools
import numpy as np
from rosbags.highlevel import AnyReader


def line_value(taus, adev, slope, keep, at):
    b = np.mean(np.log10(adev[keep]) - slope * np.log10(taus[keep]))
    return 10 ** (b + slope * np.log10(at))


def main():
    bag, topic, out = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    t0 = time.perf_counter()
    stamps, rows = [], []
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for con, _, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, con.msgtype)
            a, w = m.linear_acceleration, m.angular_velocity
            stamps.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9)
            rows.append((a.x, a.y, a.z, w.x, w.y, w.z))
    data = np.array(rows)
    rate = 1.0 / np.median(np.diff(stamps))
    t1 = time.perf_counter()
    n, k = [], []
    for axis in range(6):
        taus, adev, _, _ = allantools.oadev(data[:, axis], rate=rate, data_type="freq", taus="octave")
        n.append(line_value(taus, adev, -0.5, taus <= 10.0, 1.0))
        k.append(line_value(taus, adev, 0.5, taus >= 100.0, 3.0))
    mean = lambda v: float(np.sqrt(np.mean(np.square(v))))
    with open(out, "w") as f:
        f.write(f"accelerometer_noise_density: {mean(n[:3]):.6e}\n")
        f.write(f"accelerometer_random_walk: {mean(k[:3]):.6e}\n")
        f.write(f"gyroscope_noise_density: {mean(n[3:]):.6e}\n")
        f.write(f"gyroscope_random_walk: {mean(k[3:]):.6e}\n")
        f.write(f"rostopic: {topic}\nupdate_rate: {rate:.1f}\n")
    print(f"read {len(rows)} messages in {t1 - t0:.2f} s, Allan deviations and lines in {time.perf_counter() - t1:.2f} s")


if __name__ == "__main__":
    main()
