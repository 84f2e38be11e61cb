"""ROS 1 and ROS 2 bags written here with rosbags' own writers (from a TUM file) read back to
the same trajectory as the TUM file, for every supported message type and for /tf frames; and
the command reads them with --topic and evo's ``bag BAGFILE REF_TOPIC EST_TOPIC`` form."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
from conftest import require

from microlie import traj as T
from microlie.cli import main
from microlie.data import example_paths

TOPICS = {
    "/pose": "geometry_msgs/msg/PoseStamped",
    "/pose_cov": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/odom": "nav_msgs/msg/Odometry",
    "/tf": "tf2_msgs/msg/TFMessage",
}


def _messages(store, rows: np.ndarray, ros1: bool):
    """Yield (topic, stamp_ns, message) for every row ``t x y z qx qy qz qw``."""
    ty = store.types
    for k, (t, x, y, z, qx, qy, qz, qw) in enumerate(rows.tolist()):
        sec = math.floor(t)
        nsec = round((t - sec) * 1e9)
        stamp = ty["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        hdr = dict(stamp=stamp, frame_id="map")
        if ros1:
            hdr["seq"] = k

        def header(frame="map", hdr=hdr):
            return ty["std_msgs/msg/Header"](**{**hdr, "frame_id": frame})

        point = ty["geometry_msgs/msg/Point"](x=x, y=y, z=z)
        quat = ty["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
        pose = ty["geometry_msgs/msg/Pose"](position=point, orientation=quat)
        cov = ty["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
        twist = ty["geometry_msgs/msg/TwistWithCovariance"](
            twist=ty["geometry_msgs/msg/Twist"](
                linear=ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                angular=ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36))
        ns = sec * 10**9 + nsec
        yield "/pose", ns, ty["geometry_msgs/msg/PoseStamped"](header=header(), pose=pose)
        yield "/pose_cov", ns, ty["geometry_msgs/msg/PoseWithCovarianceStamped"](
            header=header(), pose=cov)
        yield "/odom", ns, ty["nav_msgs/msg/Odometry"](header=header(), child_frame_id="base",
                                                       pose=cov, twist=twist)

        def tf(parent, child, tx, quat=quat, header=header):
            return ty["geometry_msgs/msg/TransformStamped"](
                header=header(parent), child_frame_id=child,
                transform=ty["geometry_msgs/msg/Transform"](
                    translation=ty["geometry_msgs/msg/Vector3"](x=tx[0], y=tx[1], z=tx[2]),
                    rotation=quat))

        # the wanted transform between two distractors in the same message
        yield "/tf", ns, ty["tf2_msgs/msg/TFMessage"](transforms=[
            tf("odom", "base", (0.0, 0.0, 0.0)), tf("map", "base", (x, y, z)),
            tf("base", "camera", (1.0, 2.0, 3.0))])


def write_bag(path, rows: np.ndarray, ros1: bool) -> None:
    require("rosbags")
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from microlie.traj.rosbag import typestore

    store = typestore(Stores, get_types_from_msg, get_typestore, ros1=ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        serialize = store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=9)
        serialize = store.serialize_cdr
    with writer:
        conns = {t: writer.add_connection(t, m, typestore=store) for t, m in TOPICS.items()}
        for topic, ns, msg in _messages(store, rows, ros1):
            writer.write(conns[topic], ns, serialize(msg, TOPICS[topic]))


@pytest.fixture(scope="module", params=["ros1", "ros2"])
def bag(request, tmp_path_factory):
    tum = example_paths()[1]
    path = tmp_path_factory.mktemp(request.param) / ("run.bag" if request.param == "ros1"
                                                     else "run")
    write_bag(path, np.loadtxt(tum), request.param == "ros1")
    return path, T.read_tum(tum)


@pytest.mark.parametrize("topic", ["/pose", "/pose_cov", "/odom", "/tf:map.base"])
def test_bag_reads_back_the_tum_trajectory(bag, topic):
    path, tum = bag
    t = T.read_trajectory(path, "bag", topic=topic)
    np.testing.assert_array_equal(t.timestamps, tum.timestamps)
    np.testing.assert_array_equal(t.positions, tum.positions)
    np.testing.assert_allclose(t.quat_xyzw, tum.quat_xyzw, rtol=0, atol=2e-16)


def test_bag_topics_and_errors(bag):
    path, _ = bag
    from microlie.traj.rosbag import bag_topics

    assert bag_topics(path) == TOPICS
    with pytest.raises(ValueError, match="no topic '/nope'.*/odom"):
        T.read_trajectory(path, "bag", topic="/nope")
    with pytest.raises(ValueError, match="PARENT.CHILD"):
        T.read_trajectory(path, "bag", topic="/tf")
    with pytest.raises(ValueError, match="no transform map -> camera"):
        T.read_trajectory(path, "bag", topic="/tf:map.camera")


def test_command_reads_bags_both_ways(bag):
    path, tum = bag
    gt = str(example_paths()[0])

    def stats(*argv):
        out, err = io.StringIO(), io.StringIO()
        assert main([*argv, "--json"], out=out, err=err) == 0, err.getvalue()
        return json.loads(out.getvalue())["stats"]

    from_tum = stats("ape", gt, str(example_paths()[1]), "-a")
    assert stats("ape", gt, str(path), "--topic", "/odom", "-a") == from_tum
    # evo's form: bag BAGFILE REF_TOPIC EST_TOPIC (here both topics hold the same poses)
    same = stats("ape", "bag", str(path), "/pose", "/tf:map.base")
    assert same["max"] == pytest.approx(0.0, abs=1e-12)
    out = io.StringIO()
    folder = path.parent / "converted"
    assert main(["traj", "bag", str(path), "/pose", "/tf:map.base", "--save-as", "tum",
                 str(folder)], out=out, err=io.StringIO()) == 0
    assert out.getvalue().count(f"poses {len(tum)}") == 2
    for name in ("pose", "tf_map_base"):
        back = T.read_tum(folder / f"{path.stem}_{name}.tum")
        np.testing.assert_array_equal(back.timestamps, tum.timestamps)
        np.testing.assert_allclose(back.matrices(), tum.matrices(), atol=1e-15)
