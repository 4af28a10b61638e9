"""ROS 2 bags into the sensor-log format (:mod:`twin.logs.format`): ``sensor_msgs/msg/Imu``
becomes ``imu.csv``, ``sensor_msgs/msg/JointState`` (the two wheel joints) ``encoders.csv``.

The bag is read with `rosbags <https://gitlab.com/ternaris/rosbags>`_ (Apache-2.0, pure
Python, no ROS installation): a rosbag2 directory (``metadata.yaml`` beside its ``.mcap`` or
``.db3`` files) or a bare ``.mcap`` file. Messages deserialise with the definitions the bag
holds (rosbag2 and MCAP files embed them), else with the ROS 2 Humble definitions rosbags
bundles. It is an optional dependency: ``pip install "mtwip-twin[ros]"`` (or ``pip install
rosbags``).

What becomes what:

* time: ``header.stamp`` (sec + nanosec), in seconds after the first message of the two
  topics (one clock for both streams, as the format wants), computed in integer nanoseconds
  so a stamp 5 ms after the first reads ``0.005``. Each stream is sorted by stamp (stably):
  a bag stores messages in the order they were recorded, which need not be their stamps'.
  With ``clock="bag"`` the recording time (when the bag received the message) is used
  instead, for drivers that leave ``header.stamp`` at zero. Note the format's ``t`` is when
  a reading reached the estimator; a stamp is when the sensor took it, earlier by the
  driver's and the transport's latency.
* IMU: ``angular_velocity`` (rad/s) → gyro_x, gyro_y, gyro_z; ``linear_acceleration``
  (m/s², gravity included: +g on z at rest) → accel_x, accel_y, accel_z; ``orientation`` is
  not used. A message whose ``angular_velocity_covariance[0]`` (or
  ``linear_acceleration_covariance[0]``) is -1, sensor_msgs' mark of "no such estimate", or
  whose values are not finite, leaves those fields empty (nothing arrived, in the format).
* Axes: REP-103's body frame (``base_link``) is x forward, y left, z up, the twin's body
  axes (x forward, y along the axle to the left, z up the body): nothing is rotated. The
  IMU's message is taken to be in that frame already (its ``header.frame_id`` is not
  transformed); an IMU mounted otherwise needs its readings rotated into ``base_link``'s
  axes first (by its driver, or when the bag is made).
* Encoders: a JointState's ``position`` of a wheel joint (rad) is the wheel's angle relative
  to the body, which is what the twin's encoders measure. ``counts = floor(sign × position ×
  counts_per_rev / 2π)``, the twin's own encoder rule (:mod:`twin.sensors.suite`), except that
  a value within 1e-6 counts of a whole number is that number: a driver that publishes its
  counts as ``counts × 2π / counts_per_rev`` gets its counts back, not one fewer through
  floating-point rounding. ``joint_signs`` is +1 for a joint whose axis is the body's +y (a
  wheel rolling forward turns positive, as in the twin's URDF) and -1 for one whose axis is
  -y. Only messages holding both joints' positions make a row; others are counted as skipped.

``log.toml`` and ``commands.csv`` are the caller's (the bag holds no control instants in the
twin's sense, nor the robot's figures): :func:`import_bag` writes the two streams and returns
what it found.
"""
from __future__ import annotations

import math
from pathlib import Path

from twin.errors import TwinError, shown

try:  # optional: the [ros] extra
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
except ImportError:  # pragma: no cover - exercised by monkeypatching in the tests
    AnyReader = None

IMU_TYPE = "sensor_msgs/msg/Imu"
JOINTS_TYPE = "sensor_msgs/msg/JointState"
INSTALL = 'pip install "mtwip-twin[ros]" (or pip install rosbags)'
WHOLE_COUNT_TOLERANCE = 1e-6  # counts: a position this close to a whole count is that count
IMU_HEADER = ("t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")  # twin.logs.format.STREAMS
ENCODERS_HEADER = ("t", "left", "right")


def import_bag(bag_path, out_dir, imu_topic: str | None = None, joints_topic: str | None = None,
               joint_names=("left_wheel_joint", "right_wheel_joint"), counts_per_rev: int = 1200,
               joint_signs=(1, 1), clock: str = "header") -> dict:
    """Read the IMU and wheel-joint topics of ROS 2 bag ``bag_path`` and write ``imu.csv`` and
    ``encoders.csv`` (the sensor-log format's streams) into ``out_dir`` (created if needed;
    the two files are replaced). See the module docstring for the mapping.

    ``imu_topic`` / ``joints_topic``: the topics to read; None takes the bag's one topic of
    type ``sensor_msgs/msg/Imu`` / ``sensor_msgs/msg/JointState``. ``joint_names``: the left
    and the right wheel joints' names in the JointState messages. ``counts_per_rev``: the
    encoder counts per wheel revolution the counts are expressed in (log.toml's
    ``encoder_counts``). ``joint_signs``: (left, right), +1 or -1 (see above). ``clock``:
    ``"header"`` (the messages' ``header.stamp``) or ``"bag"`` (when the bag recorded them).

    Returns a dict: ``bag``, ``topics`` (every topic of the bag: its type and message count),
    ``imu_topic``, ``joints_topic``, ``imu_messages``, ``joint_messages``, ``imu_rows``,
    ``encoder_rows``, ``skipped_joint_messages`` (without both wheels' finite positions),
    ``imu_without_gyro``, ``imu_without_accel``, ``first_stamp`` (s, the clock's time of
    t = 0, for ROS clocks seconds since the Unix epoch), ``first_stamp_ns``, ``span`` (s,
    from the first message to the last), ``clock``, ``counts_per_rev``, ``joint_names``.

    Anything wrong is one :class:`~twin.errors.TwinError` line naming the bag (and the
    topic): rosbags not installed, a bag that cannot be read, a missing topic, a topic of
    another type, a joint name the messages do not hold, a zero ``header.stamp``.
    """
    if AnyReader is None:
        raise TwinError(f"reading ROS 2 bags needs the rosbags library, which is not installed: {INSTALL}")
    bag = Path(bag_path)
    names = _joint_names(joint_names)
    signs = _signs(joint_signs)
    cpr = counts_per_rev
    if isinstance(cpr, bool) or not isinstance(cpr, int) or not 4 <= cpr <= 10_000_000:
        raise TwinError(f"counts_per_rev: {shown(cpr)}; allowed: an integer from 4 to 10000000 "
                        f"(counts per wheel revolution)")
    if clock not in ("header", "bag"):
        raise TwinError(f"clock: {shown(clock)}; allowed: 'header' (header.stamp) or 'bag' (recording time)")
    if not bag.exists():
        raise TwinError(f"{bag}: no such ROS 2 bag (a rosbag2 directory with metadata.yaml, or a .mcap file)")

    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # noqa: BLE001 -- the library's errors, and a corrupt file's anything
        raise TwinError(f"{bag}: cannot be read as a ROS 2 bag ({_one_line(exc)})") from None
    try:
        topics = {}
        for c in reader.connections:
            typ, n = topics.get(c.topic, (c.msgtype, 0))
            topics[c.topic] = (typ if typ == c.msgtype else f"{typ}|{c.msgtype}", n + c.msgcount)
        imu_topic = _topic(bag, topics, imu_topic, IMU_TYPE, "imu_topic")
        joints_topic = _topic(bag, topics, joints_topic, JOINTS_TYPE, "joints_topic")
        imu_rows, imu_stats = [], {"imu_messages": 0, "imu_without_gyro": 0, "imu_without_accel": 0}
        enc_rows, enc_stats = [], {"joint_messages": 0, "skipped_joint_messages": 0}
        seen_names: set[str] = set()
        conns = [c for c in reader.connections if c.topic in (imu_topic, joints_topic)]
        try:
            for conn, rec_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                where = f"{bag}: topic {conn.topic}"
                ns = rec_ns if clock == "bag" else _stamp_ns(msg, where)
                if conn.topic == imu_topic:
                    imu_stats["imu_messages"] += 1
                    row = _imu_row(msg, imu_stats)
                    if row is not None:
                        imu_rows.append((ns, row))
                else:
                    enc_stats["joint_messages"] += 1
                    seen_names.update(msg.name)
                    counts = _counts(msg, names, signs, cpr)
                    if counts is None:
                        enc_stats["skipped_joint_messages"] += 1
                    else:
                        enc_rows.append((ns, counts))
        except TwinError:
            raise
        except Exception as exc:  # noqa: BLE001 -- a truncated file, a message that does not deserialise
            raise TwinError(f"{bag}: cannot be read as a ROS 2 bag ({_one_line(exc)})") from None
    finally:
        reader.close()

    if not imu_rows:
        raise TwinError(f"{bag}: topic {imu_topic}: no message holds angular_velocity or linear_acceleration "
                        f"({imu_stats['imu_messages']} message(s)); the log needs IMU readings")
    if not enc_rows:
        missing = [n for n in names if n not in seen_names]
        if missing:
            raise TwinError(f"{bag}: topic {joints_topic}: no joint named {missing[0]!r}; the messages hold "
                            f"{_listing(sorted(seen_names))} (pass joint_names=(left, right))")
        raise TwinError(f"{bag}: topic {joints_topic}: no message holds finite positions of both "
                        f"{names[0]!r} and {names[1]!r} ({enc_stats['joint_messages']} message(s))")
    imu_rows.sort(key=lambda r: r[0])
    enc_rows.sort(key=lambda r: r[0])
    t0 = min(imu_rows[0][0], enc_rows[0][0])
    t1 = max(imu_rows[-1][0], enc_rows[-1][0])

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "imu.csv", "w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(IMU_HEADER) + "\n")
            for ns, row in imu_rows:
                fh.write(",".join([repr((ns - t0) / 1e9), *row]) + "\n")
        with open(out / "encoders.csv", "w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(ENCODERS_HEADER) + "\n")
            for ns, (left, right) in enc_rows:
                fh.write(f"{(ns - t0) / 1e9!r},{left},{right}\n")
    except OSError as exc:
        raise TwinError(f"{out}: cannot write the log's streams ({_one_line(exc)})") from None
    return {"bag": str(bag), "topics": topics, "imu_topic": imu_topic, "joints_topic": joints_topic,
            **imu_stats, **enc_stats, "imu_rows": len(imu_rows), "encoder_rows": len(enc_rows),
            "first_stamp": t0 / 1e9, "first_stamp_ns": t0, "span": (t1 - t0) / 1e9, "clock": clock,
            "counts_per_rev": cpr, "joint_names": names}


def _topic(bag: Path, topics: dict, topic, want: str, arg: str) -> str:
    """The topic to read: ``topic`` checked, or the bag's one topic of type ``want``."""
    if topic is None:
        found = sorted(t for t, (typ, _) in topics.items() if typ == want)
        if len(found) == 1:
            return found[0]
        if not found:
            raise TwinError(f"{bag}: no topic of type {want}; the bag holds {_listing(_typed(topics))}")
        raise TwinError(f"{bag}: {len(found)} topics of type {want} ({_listing(found)}); pass {arg}= one of them")
    if topic not in topics:
        raise TwinError(f"{bag}: topic {topic}: not in the bag; it holds {_listing(_typed(topics))}")
    typ = topics[topic][0]
    if typ != want:
        raise TwinError(f"{bag}: topic {topic}: its messages are {typ}; {arg} must be a {want} topic")
    return topic


def _stamp_ns(msg, where: str) -> int:
    stamp = msg.header.stamp
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    if ns == 0:
        raise TwinError(f"{where}: a message's header.stamp is zero (the driver does not stamp its "
                        f"messages); pass clock='bag' to use the recording time")
    return ns


def _imu_row(msg, stats: dict):
    """The six fields of an IMU row as text (empty where nothing arrived), or None if neither did."""
    fields = []
    for vec, cov, key in ((msg.angular_velocity, msg.angular_velocity_covariance, "imu_without_gyro"),
                          (msg.linear_acceleration, msg.linear_acceleration_covariance, "imu_without_accel")):
        v = (float(vec.x), float(vec.y), float(vec.z))
        if float(cov[0]) == -1.0 or not all(math.isfinite(x) for x in v):
            stats[key] += 1
            fields += ["", "", ""]
        else:
            fields += [repr(x) for x in v]
    return None if all(f == "" for f in fields) else fields


def _counts(msg, names, signs, cpr: int):
    """(left, right) encoder counts from a JointState message, or None if it lacks either."""
    joint = list(msg.name)
    pos = msg.position
    out = []
    for name, sign in zip(names, signs):
        if name not in joint:
            return None
        i = joint.index(name)
        if i >= len(pos) or not math.isfinite(float(pos[i])):
            return None
        x = sign * float(pos[i]) * cpr / (2.0 * math.pi)
        k = round(x)
        out.append(k if abs(x - k) <= WHOLE_COUNT_TOLERANCE else math.floor(x))
    return tuple(out)


def _joint_names(names):
    ok = isinstance(names, (tuple, list)) and len(names) == 2 and all(isinstance(n, str) and n for n in names)
    if not ok or names[0] == names[1]:
        raise TwinError(f"joint_names: {shown(names)}; allowed: (left, right), two different joint names")
    return (names[0], names[1])


def _signs(signs):
    if not (isinstance(signs, (tuple, list)) and len(signs) == 2 and all(
            not isinstance(s, bool) and s in (1, -1) for s in signs)):
        raise TwinError(f"joint_signs: {shown(signs)}; allowed: (left, right), each 1 or -1 (-1 for a joint "
                        f"whose axis is the body's -y)")
    return (int(signs[0]), int(signs[1]))


def _typed(topics: dict) -> list[str]:
    return [f"{t} ({typ})" for t, (typ, _) in sorted(topics.items())]


def _listing(items, limit: int = 6) -> str:
    items = list(items)
    if not items:
        return "none"
    more = f", … ({len(items) - limit} more)" if len(items) > limit else ""
    return ", ".join(items[:limit]) + more


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:199] + "…"


__all__ = ["IMU_TYPE", "JOINTS_TYPE", "import_bag"]
