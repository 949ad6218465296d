"""rmw_zenoh's and the bridge's wire format (depthguard.live.wire), pinned by golden strings and bytes taken from
rmw_zenoh's sources and design document and from ROS 2's published type hashes."""

import numpy as np
import pytest

from depthguard.errors import InputError
from depthguard.live import wire

IMAGE_HASH = "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
FLOAT64_ARRAY_HASH = "RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # rmw_zenoh's design.md


def test_type_hashes_are_ros_2s():
    assert wire.type_hash("sensor_msgs/msg/Image") == IMAGE_HASH
    assert wire.type_hash("std_msgs/msg/Float64MultiArray") == FLOAT64_ARRAY_HASH
    assert wire.type_hash("std_msgs/msg/String") == STRING_HASH


def test_keys_in_each_layout():
    assert wire.data_key("/cam/depth/image_raw", "sensor_msgs/msg/Image") == \
        f"0/cam/depth/image_raw/sensor_msgs::msg::dds_::Image_/{IMAGE_HASH}"
    assert wire.data_key("/depthguard/distances", "std_msgs/msg/Float64MultiArray", domain=7) == \
        f"7/depthguard/distances/std_msgs::msg::dds_::Float64MultiArray_/{FLOAT64_ARRAY_HASH}"
    assert wire.subscription_key("/joint_states", "sensor_msgs/msg/JointState") == \
        "0/joint_states/sensor_msgs::msg::dds_::JointState_/*"
    assert wire.data_key("/cam/depth/image_raw", "sensor_msgs/msg/Image", layout="bridge") == "cam/depth/image_raw"
    assert wire.key_type_hash(wire.data_key("/a", "sensor_msgs/msg/Image")) == IMAGE_HASH
    assert wire.key_type_hash("a/b") is None


@pytest.mark.parametrize("bad", ["", "/", "a//b", "/a b", "/1a"])
def test_bad_topic_names_are_refused(bad):
    with pytest.raises(InputError, match="topic"):
        wire.data_key(bad, "sensor_msgs/msg/Image")


def test_attachment_bytes():
    data = wire.attachment_bytes(1, 0x0102030405060708, bytes(range(16)))
    assert data.hex() == "0100000000000000" "0807060504030201" "10" + bytes(range(16)).hex()
    parsed = wire.parse_attachment(data)
    assert (parsed.sequence, parsed.source_ns, parsed.gid) == (1, 0x0102030405060708, bytes(range(16)))
    assert wire.parse_attachment(None) is None and wire.parse_attachment(data[:-1]) is None


def test_liveliness_tokens():
    assert wire.liveliness_key("abc", 0, "NN", "depthguard") == "@ros2_lv/0/abc/0/0/NN/%/%/depthguard"
    assert wire.liveliness_key("abc", 3, "MP", "depthguard", "/depthguard/distances",
                               "std_msgs/msg/Float64MultiArray") == (
        "@ros2_lv/0/abc/0/3/MP/%/%/depthguard/%depthguard%distances/std_msgs::msg::dds_::Float64MultiArray_/"
        f"{FLOAT64_ARRAY_HASH}/::,10:,:,:,,")


def test_cdr_of_a_distances_message():
    types = wire.type_store().types
    layout = types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
    message = types["std_msgs/msg/Float64MultiArray"](layout=layout, data=np.array([0.5, np.inf]))
    data = wire.serialize(message, "std_msgs/msg/Float64MultiArray")
    # header; layout.dim (empty), layout.data_offset; data's length 2, 4 bytes of padding (float64 is 8-aligned from
    # the body's start), 0.5 and inf little endian
    assert data.hex() == ("00010000" "00000000" "00000000" "02000000" "00000000" "000000000000e03f"
                          "000000000000f07f")
    back = wire.deserialize(data, "std_msgs/msg/Float64MultiArray")
    assert list(back.data) == [0.5, np.inf]
    with pytest.raises(InputError, match="CDR"):
        wire.deserialize(b"\x07\x07", "std_msgs/msg/Float64MultiArray")
    with pytest.raises(InputError, match="CDR"):
        wire.deserialize(data[:-3], "std_msgs/msg/Float64MultiArray")


def test_topic_names_expand_as_ros_2_expands_them_in_the_node():
    """issue 36: ``~`` and relative names are the node's (/depthguard), never keyed literally; substitutions and
    names ROS 2 refuses are named errors."""
    assert wire.ros_name("~") == "/depthguard"
    assert wire.ros_name("~/speed_scaling") == "/depthguard/speed_scaling"
    assert wire.ros_name("cam/depth/image_raw") == "/cam/depth/image_raw"
    assert wire.ros_name("/cam/depth/image_raw/") == "/cam/depth/image_raw"
    assert wire.data_key("~/x", "sensor_msgs/msg/Image", "bridge") == "depthguard/x"
    assert wire.data_key("a/b", "sensor_msgs/msg/Image").startswith("0/a/b/sensor_msgs::msg::dds_::Image_/RIHS01_")
    key = wire.liveliness_key("abc", 11, "MS", "depthguard", "~/x", "sensor_msgs/msg/Image", qos=wire.SENSOR_QOS)
    assert "/%depthguard%x/" in key
    for bad in ("{node}/x", "//a", "", "1a", "/a b", "~x", "a/~", "/a/1b", None, 3):
        with pytest.raises(InputError) as info:
            wire.ros_name(bad)
        assert info.value.field == "topic"


def test_liveliness_tokens_read_back():
    key = wire.liveliness_key("abc", 11, "MS", "depthguard", "/cam/depth/image_raw", "sensor_msgs/msg/Image", domain=5,
                              qos=wire.SENSOR_QOS)
    token = wire.parse_liveliness_key(key)
    assert token == wire.Token(5, "abc", "MS", "depthguard", "/cam/depth/image_raw", "sensor_msgs::msg::dds_::Image_",
                               wire.type_hash("sensor_msgs/msg/Image"), "2::,10:,:,:,,")
    assert wire.parse_liveliness_key(wire.liveliness_key("abc", 0, "NN", "depthguard")).kind == "NN"
    for bad in ("", "@ros2_lv/x/abc/0/0/NN/%/%/n", "other/0/abc/0/0/NN/%/%/n", "@ros2_lv/0/abc/0/3/XX/%/%/n",
                "@ros2_lv/0/abc/0/3/MP/%/%/n/%t"):
        assert wire.parse_liveliness_key(bad) is None


def test_bridge_route_tokens_are_zenoh_plugin_ros2dds_s():
    """Golden tokens written by hand from zenoh-plugin-ros2dds 1.10.0 (eclipse-zenoh/zenoh-plugin-ros2dds,
    ``zenoh-plugin-ros2dds/src/liveliness_mgt.rs``, commit 09d68c0 of 2026-08-20): kedefine ``ke_liveliness_sub``
    ``@ros2_lv/${zenoh_id:*}/MS/${ke:*}/${typ:*}/${qos_ke:*}``, ``/`` written ``§`` (SLASH_REPLACEMSNT_CHAR), the
    type as ``ros2_utils.rs``'s ``dds_type_to_ros2_message_type`` gives it, and ``qos_to_key_expr``: "" for keyless,
    then reliability, durability and ``history kind,depth`` as Cyclone DDS numbers them (BEST_EFFORT 0, RELIABLE 1;
    VOLATILE 0; KEEP_LAST 0)."""
    import ros_publisher

    sub = "@ros2_lv/1f2e3d/MS/cam\u00a7depth\u00a7image_raw/sensor_msgs\u00a7msg\u00a7Image/:0:0:0,10"
    pub = ("@ros2_lv/1f2e3d/MP/depthguard\u00a7distances/std_msgs\u00a7msg\u00a7Float64MultiArray/:1:0:0,10")
    assert wire.bridge_liveliness_key("1f2e3d", "MS", "/cam/depth/image_raw", "sensor_msgs/msg/Image") == sub
    assert wire.bridge_liveliness_key("1f2e3d", "MP", "/depthguard/distances", "std_msgs/msg/Float64MultiArray") == pub
    assert wire.parse_bridge_liveliness_key(sub) == ("1f2e3d", "MS", "/cam/depth/image_raw", "sensor_msgs/msg/Image",
                                                     ":0:0:0,10")
    assert ros_publisher.bridge_route(sub)[1:4] == ("MS", "/cam/depth/image_raw", "sensor_msgs/msg/Image")
    # Relative and private names are expanded first, as for rmw_zenoh's keys.
    assert wire.bridge_liveliness_key("z", "MP", "~/x", "std_msgs/msg/String").split("/")[3] == "depthguard\u00a7x"
    # rmw_zenoh's tokens are not the bridge's: its QoS text has 6 fields.
    assert ros_publisher.bridge_route(wire.liveliness_key("z", 1, "MS", "n", "/a", "std_msgs/msg/String")) is None
    assert wire.parse_bridge_liveliness_key("@ros2_lv/0/z/0/0/NN/%/%/n") is None
    with pytest.raises(InputError, match="MP or MS"):
        wire.bridge_liveliness_key("z", "NN", "/a", "std_msgs/msg/String")


def test_subscription_token_is_rmw_zenoh_s():
    """A golden token written by hand from rmw_zenoh's own source (ros2/rmw_zenoh, rolling branch, commit bfc065f of
    2024-10-16, ``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``: ``Entity``'s key parts joined by ``/`` (admin
    space ``@ros2_lv``, domain, zid, node id, entity id, ``MS``, then enclave, namespace, node, topic, type and hash,
    each ``mangle_name``d, ``/`` written ``%``), and ``qos_to_keyexpr``: reliability:durability:history,depth:
    deadline sec,nsec:lifespan sec,nsec:liveliness,lease sec,lease nsec, each field empty where it is the default
    profile's (reliable, volatile, keep last, depth 42); RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT is 2). Not a
    released tag: the newest rmw_zenoh source reachable here."""
    expected = ("@ros2_lv/0/1f2e3d/0/11/MS/%/%/depthguard/%cam%depth%image_raw/sensor_msgs::msg::dds_::Image_/"
                f"{IMAGE_HASH}/2::,10:,:,:,,")
    assert wire.liveliness_key("1f2e3d", 11, "MS", "depthguard", "/cam/depth/image_raw", "sensor_msgs/msg/Image",
                               qos=wire.SENSOR_QOS) == expected
    parsed = wire.parse_liveliness_key(expected)
    assert (parsed.kind, parsed.topic, parsed.qos) == ("MS", "/cam/depth/image_raw", "2::,10:,:,:,,")
