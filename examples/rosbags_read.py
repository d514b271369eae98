"""The Python `rosbags` library reading what `odocal bag` reads, for the comparison in
docs/ros.md: every message of /joint_states, /imu and /odom read and deserialized, median of
3, in million messages per second, for each bag `bag_benchmark` kept.

    ODOCAL_BENCH_KEEP=/tmp/bags cargo run --release --example bag_benchmark
    python3 -m venv /tmp/rb && /tmp/rb/bin/pip install rosbags==0.11.9
    /tmp/rb/bin/python examples/rosbags_read.py /tmp/bags
"""

import sys
import time
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.typesys import Stores, get_typestore

TOPICS = {"/joint_states", "/imu", "/odom"}


def read(path: Path) -> int:
    n = 0
    if path.suffix == ".bag":
        # The benchmark's ROS 1 bags carry no message definitions: rosbags' own Noetic types
        # deserialize them.
        store = get_typestore(Stores.ROS1_NOETIC)
        with Ros1Reader(path) as reader:
            conns = [c for c in reader.connections if c.topic in TOPICS]
            for conn, _, raw in reader.messages(connections=conns):
                store.deserialize_ros1(raw, conn.msgtype)
                n += 1
        return n
    store = get_typestore(Stores.ROS2_HUMBLE)
    with AnyReader([path], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic in TOPICS]
        for conn, _, raw in reader.messages(connections=conns):
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def main() -> None:
    root = Path(sys.argv[1])
    print(f"{'bag':<24}{'messages':>10}{'s':>8}{'M msg/s':>10}")
    for path in sorted(root.iterdir()):
        times = []
        n = 0
        for _ in range(3):
            t = time.perf_counter()
            try:
                n = read(path)
            except Exception as e:  # a format rosbags does not read: say so, go on
                print(f"{path.name:<24} not read: {e}")
                break
            times.append(time.perf_counter() - t)
        if len(times) == 3:
            s = sorted(times)[1]
            print(f"{path.name:<24}{n:>10}{s:>8.2f}{n / s / 1e6:>10.3f}")


if __name__ == "__main__":
    main()
