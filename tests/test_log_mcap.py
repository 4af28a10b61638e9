"""ROS 2 bags into sensor logs (issue 28, twin.logs.mcap): a bag written here with rosbags'
own writer (MCAP storage, sensor_msgs/Imu and sensor_msgs/JointState) imports to the exact
imu.csv and encoders.csv expected, which read as a sensor log with a log.toml and commands
added; a missing topic, a wrong type, an unknown joint, a zero stamp, an unreadable bag and
a missing library are one line naming the bag (and the topic)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from twin.errors import TwinError
from twin.logs import mcap as ros
from twin.logs.format import STREAMS, read_log

BASE = 1_700_000_000  # s: the bags' first stamp
CPR = 1200
# whole counts published as angles (counts × 2π / CPR) that a plain floor of angle × CPR / 2π
# gives back one short (see test_whole_counts_need_the_tolerance)
K_LEFT, K_RIGHT = 4, -197


def stamp(ts, ms: float):
    ns = round(ms * 1e6)
    return ts.types["builtin_interfaces/msg/Time"](sec=BASE + ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def imu_msg(ts, np, ms, gyro, accel, no_gyro=False, t0=None):
    T = ts.types
    head = T["std_msgs/msg/Header"](stamp=t0 if t0 is not None else stamp(ts, ms), frame_id="base_link")
    cov = np.zeros(9)
    gcov = cov.copy()
    if no_gyro:
        gcov[0] = -1.0
    return T["sensor_msgs/msg/Imu"](
        header=head, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=cov.copy(), angular_velocity=T["geometry_msgs/msg/Vector3"](*gyro),
        angular_velocity_covariance=gcov, linear_acceleration=T["geometry_msgs/msg/Vector3"](*accel),
        linear_acceleration_covariance=cov.copy())


def joints_msg(ts, np, ms, names, positions):
    T = ts.types
    head = T["std_msgs/msg/Header"](stamp=stamp(ts, ms), frame_id="")
    return T["sensor_msgs/msg/JointState"](header=head, name=list(names), position=np.array(positions, float),
                                           velocity=np.zeros(0), effort=np.zeros(0))


GYRO = [(0.01, -0.02, 0.5), (0.25, 0.0, -0.125), (1e-3, 2e-3, 3e-3), (-0.5, 0.75, 0.0625)]
ACCEL = [(0.1, -0.05, 9.81), (0.2, 0.0, 9.79), (0.0, 0.0, 9.80665), (-0.3, 0.01, 9.83)]


def write_bag(path: Path, storage: str = "mcap", imu_topics=("/imu/data",), zero_stamp=False) -> Path:
    """A small ROS 2 bag: IMU at 1, 6, 11, 16 ms after BASE (the 11 ms one recorded after the
    16 ms one; the 6 ms one without a gyro estimate), joint states at 0, 10, 20, 30 ms (in
    another order than the wheels', with a caster; the 20 ms one without the right wheel, the
    30 ms one with a NaN position)."""
    np = pytest.importorskip("numpy")
    rosbag2 = pytest.importorskip("rosbags.rosbag2")
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    plugin = {"mcap": rosbag2.StoragePlugin.MCAP, "sqlite3": rosbag2.StoragePlugin.SQLITE3}[storage]
    with rosbag2.Writer(path, version=9, storage_plugin=plugin) as w:
        imus = [w.add_connection(t, ros.IMU_TYPE, typestore=ts) for t in imu_topics]
        js = w.add_connection("/joint_states", ros.JOINTS_TYPE, typestore=ts)
        w.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=ts)
        res = 2.0 * math.pi / CPR
        joint_states = [
            (0.0, ["caster", "right_wheel_joint", "left_wheel_joint"], [7.0, -0.01, 0.5]),
            (10.0, ["left_wheel_joint", "right_wheel_joint"], [K_LEFT * res, K_RIGHT * res]),
            (20.0, ["left_wheel_joint"], [0.6]),
            (30.0, ["left_wheel_joint", "right_wheel_joint"], [math.nan, 0.1]),
        ]
        imu = [(1.0, 0), (6.0, 1), (16.0, 3), (11.0, 2)]  # recorded out of stamp order
        events = [(ms + 0.5, "j", k) for k, (ms, _, _) in enumerate(joint_states)]
        events += [(n * 5.0 + 2.0, "i", k) for n, k in enumerate(imu)]
        for rec_ms, kind, k in sorted(events, key=lambda e: e[0]):
            rec_ns = BASE * 1_000_000_000 + round(rec_ms * 1e6)
            if kind == "j":
                ms, names, pos = joint_states[k]
                w.write(js, rec_ns, ts.serialize_cdr(joints_msg(ts, np, ms, names, pos), ros.JOINTS_TYPE))
            else:
                ms, i = k
                zero = ts.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0) if zero_stamp else None
                msg = imu_msg(ts, np, ms, GYRO[i], ACCEL[i], no_gyro=(i == 1), t0=zero)
                for c in imus:
                    w.write(c, rec_ns, ts.serialize_cdr(msg, ros.IMU_TYPE))
    return path


IMU_CSV = ("t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n"
           "0.001,0.01,-0.02,0.5,0.1,-0.05,9.81\n"
           "0.006,,,,0.2,0.0,9.79\n"
           "0.011,0.001,0.002,0.003,0.0,0.0,9.80665\n"
           "0.016,-0.5,0.75,0.0625,-0.3,0.01,9.83\n")
ENC_CSV = ("t,left,right\n"
           "0.0,95,-2\n"  # floor(0.5 × 1200 / 2π) = floor(95.49); floor(-0.01 × 1200 / 2π) = floor(-1.91)
           f"0.01,{K_LEFT},{K_RIGHT}\n")


def read(d: Path, name: str) -> str:
    return (d / name).read_text(encoding="utf-8")


def test_an_mcap_bag_imports_to_the_exact_streams(tmp_path):
    bag = write_bag(tmp_path / "bag")
    out = tmp_path / "log"
    info = ros.import_bag(bag, out, counts_per_rev=CPR)
    assert read(out, "imu.csv") == IMU_CSV
    assert read(out, "encoders.csv") == ENC_CSV
    assert read(out, "imu.csv").splitlines()[0].split(",") == list(STREAMS["imu"])
    assert read(out, "encoders.csv").splitlines()[0].split(",") == list(STREAMS["encoders"])
    assert sorted(p.name for p in out.iterdir()) == ["encoders.csv", "imu.csv"]  # log.toml, commands: the caller's
    assert info["topics"] == {"/imu/data": (ros.IMU_TYPE, 4), "/joint_states": (ros.JOINTS_TYPE, 4),
                              "/cmd_vel": ("geometry_msgs/msg/Twist", 0)}
    assert (info["imu_topic"], info["joints_topic"]) == ("/imu/data", "/joint_states")
    assert (info["imu_messages"], info["imu_rows"], info["imu_without_gyro"], info["imu_without_accel"]) == (4, 4, 1, 0)
    assert (info["joint_messages"], info["encoder_rows"], info["skipped_joint_messages"]) == (4, 2, 2)
    assert info["first_stamp_ns"] == BASE * 1_000_000_000 and info["first_stamp"] == float(BASE)
    assert info["span"] == 0.016 and info["clock"] == "header"


def test_the_streams_read_as_a_sensor_log(tmp_path):
    out = tmp_path / "log"
    ros.import_bag(write_bag(tmp_path / "bag"), out, counts_per_rev=CPR)
    (out / "log.toml").write_text('format = "mtwip-sensor-log"\nversion = 1\ncontrol_rate = 200.0\n'
                                  'wheel_radius = 0.04\ntrack = 0.30\nencoder_counts = 1200\n'
                                  'imu_position = [0.0, 0.0, 0.1]\n', encoding="utf-8")
    (out / "commands.csv").write_text("t,ul,ur\n0.0,0.0,0.0\n0.005,0.0,0.0\n", encoding="utf-8")
    log = read_log(out)
    assert log.imu_t.tolist() == [0.001, 0.006, 0.011, 0.016]
    assert math.isnan(log.gyro[1, 0]) and log.gyro[0].tolist() == [0.01, -0.02, 0.5]
    assert log.accel[2].tolist() == [0.0, 0.0, 9.80665]
    assert log.encoders_t.tolist() == [0.0, 0.01] and log.counts.tolist() == [[95, -2], [K_LEFT, K_RIGHT]]


def test_a_bare_mcap_file_and_a_sqlite3_bag_import_the_same(tmp_path):
    bag = write_bag(tmp_path / "bag")
    (mcap_file,) = bag.glob("*.mcap")
    ros.import_bag(mcap_file, tmp_path / "a", counts_per_rev=CPR)
    assert read(tmp_path / "a", "imu.csv") == IMU_CSV and read(tmp_path / "a", "encoders.csv") == ENC_CSV
    ros.import_bag(write_bag(tmp_path / "db", storage="sqlite3"), tmp_path / "b", counts_per_rev=CPR)
    assert read(tmp_path / "b", "imu.csv") == IMU_CSV and read(tmp_path / "b", "encoders.csv") == ENC_CSV


def test_whole_counts_need_the_tolerance():
    res = 2.0 * math.pi / CPR
    for k in (K_LEFT, K_RIGHT):  # why the 1e-6 counts tolerance
        assert math.floor(k * res * CPR / (2.0 * math.pi)) == k - 1


def test_joint_signs_and_the_bag_clock(tmp_path):
    bag = write_bag(tmp_path / "bag")
    ros.import_bag(bag, tmp_path / "a", counts_per_rev=CPR, joint_signs=(1, -1))
    assert read(tmp_path / "a", "encoders.csv") == f"t,left,right\n0.0,95,1\n0.01,{K_LEFT},{-K_RIGHT}\n"
    info = ros.import_bag(bag, tmp_path / "b", counts_per_rev=CPR, clock="bag")  # recorded 0.5 ms after stamps
    assert read(tmp_path / "b", "encoders.csv") == f"t,left,right\n0.0,95,-2\n0.01,{K_LEFT},{K_RIGHT}\n"
    imu_t = [row.split(",")[0] for row in read(tmp_path / "b", "imu.csv").splitlines()[1:]]
    assert imu_t == ["0.0015", "0.0065", "0.0115", "0.0165"]  # recording order, as the bag's messages
    assert info["first_stamp_ns"] == BASE * 1_000_000_000 + 500_000


def one_line(exc_info, *parts):
    text = str(exc_info.value)
    assert "\n" not in text, text
    for p in parts:
        assert p in text, text
    return text


def test_a_missing_topic_a_wrong_type_and_an_unknown_joint(tmp_path):
    bag = write_bag(tmp_path / "bag")
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o", imu_topic="/imu/raw")
    one_line(e, str(bag), "/imu/raw", "not in the bag", "/imu/data (sensor_msgs/msg/Imu)")
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o", imu_topic="/joint_states")
    one_line(e, str(bag), "topic /joint_states", "sensor_msgs/msg/JointState", "imu_topic must be a sensor_msgs/msg/Imu")
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o", joints_topic="/cmd_vel")
    one_line(e, str(bag), "topic /cmd_vel", "geometry_msgs/msg/Twist")
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o", joint_names=("wheel_left_joint", "wheel_right_joint"))
    one_line(e, str(bag), "topic /joint_states", "no joint named 'wheel_left_joint'",
             "caster, left_wheel_joint, right_wheel_joint")
    assert not (tmp_path / "o").exists()  # nothing written on an error


def test_no_topic_of_the_type_or_several(tmp_path):
    bag = write_bag(tmp_path / "bag", imu_topics=("/imu/a", "/imu/b"))
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o")
    one_line(e, str(bag), "2 topics of type sensor_msgs/msg/Imu", "/imu/a, /imu/b", "imu_topic=")
    ros.import_bag(bag, tmp_path / "o", imu_topic="/imu/b", counts_per_rev=CPR)
    assert read(tmp_path / "o", "imu.csv") == IMU_CSV
    bag = write_bag(tmp_path / "bag2", imu_topics=())
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o2")
    one_line(e, str(bag), "no topic of type sensor_msgs/msg/Imu", "/joint_states (sensor_msgs/msg/JointState)")


def test_a_zero_stamp_an_unreadable_bag_and_bad_arguments(tmp_path):
    bag = write_bag(tmp_path / "bag", zero_stamp=True)
    with pytest.raises(TwinError) as e:
        ros.import_bag(bag, tmp_path / "o")
    one_line(e, str(bag), "topic /imu/data", "header.stamp is zero", "clock='bag'")
    with pytest.raises(TwinError) as e:
        ros.import_bag(tmp_path / "nothing", tmp_path / "o")
    one_line(e, "nothing", "no such ROS 2 bag")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    with pytest.raises(TwinError) as e:
        ros.import_bag(junk, tmp_path / "o")
    one_line(e, str(junk), "cannot be read as a ROS 2 bag")
    for kwargs, part in (({"counts_per_rev": 2.5}, "counts_per_rev"), ({"joint_signs": (1, 2)}, "joint_signs"),
                         ({"joint_names": ("a", "a")}, "joint_names"), ({"clock": "wall"}, "clock")):
        with pytest.raises(TwinError) as e:
            ros.import_bag(bag, tmp_path / "o", **kwargs)
        one_line(e, part)


def test_without_the_library_one_line_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setattr(ros, "AnyReader", None)
    with pytest.raises(TwinError) as e:
        ros.import_bag(tmp_path / "bag", tmp_path / "o")
    one_line(e, "rosbags", "pip install")
