"""ROS 2 topics on zenoh as rmw_zenoh and zenoh-bridge-ros2dds lay them out (design §12b): keys, type hashes,
payloads, attachments and liveliness tokens. Pure functions of strings and bytes: no zenoh in here.

**rmw_zenoh** (ROS 2's zenoh middleware, Jazzy on; ``rmw_zenoh_cpp``'s ``liveliness_utils.cpp``,
``attachment_helpers.cpp`` and ``docs/design.md``):

- data key: ``<domain>/<topic without its leading and trailing slash>/<pkg>::msg::dds_::<Name>_/RIHS01_<64 hex>``,
  e.g. ``0/cam/depth/image_raw/sensor_msgs::msg::dds_::Image_/RIHS01_d31d41a9...``;
- payload: the CDR encapsulation header ``00 01 00 00`` (little-endian CDR) and the message's CDR body;
- attachment, 33 bytes, mandatory (a subscriber drops a sample without one): the sequence number (int64, little
  endian, from 1), the source time (int64 nanoseconds since the epoch), 16 (one byte, the gid's length) and the
  publisher's 16-byte gid;
- liveliness token per entity: ``@ros2_lv/<domain>/<zenoh id>/<node id>/<entity id>/<MP|MS|NN>/<enclave>/
  <namespace>/<node>/<topic>/<type>/<hash>/<qos>``, each name with ``/`` written ``%``; the QoS as
  ``reliability:durability:history,depth:deadline:lifespan:liveliness``, a field left empty where it is rmw_zenoh's
  default (reliable, volatile, keep last, depth 42).

**zenoh-bridge-ros2dds** (ROS 2 on DDS, bridged; ``zenoh-plugin-ros2dds``'s ``liveliness_mgt.rs``,
``ros2_utils.rs`` and ``routes_mgr.rs``, 1.10.0): the key is the topic without its leading slash, the payload the
same CDR bytes, and no attachment. The bridges announce their routes to each other with liveliness tokens
``@ros2_lv/<zenoh id>/<MP|MS>/<key>/<pkg/msg/Name>/<qos>``, each ``/`` in the key and the type written ``§``, the
QoS as ``<K if keyed>:<reliability>:<durability>:<history>,<depth>`` in DDS's numbers (best effort 0, reliable 1;
volatile 0, transient local 1; keep last 0, keep all 1). A bridge that sees another session's ``MS`` token creates a
DDS reader of that topic, and for an ``MP`` token a DDS writer (:func:`bridge_liveliness_key`): so the DDS camera
drivers count a subscriber, and ``ros2 topic list`` on the DDS side shows depthguard's outputs.

Type hashes come from ``rosbags``' type store (ROS 2 Jazzy's definitions), which also serialises the messages.
rosidl gives Humble's messages the same hashes, but rmw_zenoh on Humble does not use them: it keys every topic, and
writes every token, with ``TypeHashNotSupported`` (``distro="humble"``; the node takes the style from its peers'
tokens, :func:`distros_of`). Older rmw_zenoh releases' attachments (named fields) are not spoken.

Every entity depthguard declares has its liveliness token, subscriptions included (kind ``MS``, best effort and
volatile: :data:`SENSOR_QOS`): camera drivers that publish only while they count a subscriber (image_transport,
realsense-ros) count depthguard. Topic names follow ROS 2's rules in the node ``/depthguard`` (:func:`ros_name`).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

from depthguard.errors import InputError

__all__ = ["LAYOUTS", "Attachment", "Token", "type_store", "type_name", "type_hash", "ros_name", "data_key",
           "subscription_key", "key_type_hash", "attachment_bytes", "parse_attachment", "liveliness_key",
           "parse_liveliness_key", "hash_of", "distros_of", "DISTROS", "HUMBLE_HASH", "serialize", "deserialize",
           "CDR_HEADER", "DEFAULT_QOS", "SENSOR_QOS", "bridge_liveliness_key", "entity_token", "parse_bridge_liveliness_key",
           "BRIDGE_SENSOR_QOS", "BRIDGE_DEFAULT_QOS"]

LAYOUTS = ("rmw_zenoh", "bridge")
#: rmw_zenoh's type-hash styles: Jazzy on key topics with the type's RIHS01 hash, Humble with this word instead.
DISTROS = ("jazzy", "humble")
HUMBLE_HASH = "TypeHashNotSupported"
#: rmw_zenoh's entity kinds in liveliness tokens: node, publisher, subscription, service server and client.
_KINDS = ("NN", "MP", "MS", "SS", "SC")
#: Little-endian plain CDR (encapsulation kind 0x0001, options 0).
CDR_HEADER = b"\x00\x01\x00\x00"
_GID_SIZE = 16
_ATTACHMENT = struct.Struct("<qqB")
_TOPIC = re.compile(r"(?:~|~/[A-Za-z_][A-Za-z0-9_]*(?:/[A-Za-z_][A-Za-z0-9_]*)*|/?[A-Za-z_][A-Za-z0-9_]*"
                    r"(?:/[A-Za-z_][A-Za-z0-9_]*)*)/?")
#: The node's name and namespace, against which ``~`` and relative topic names expand (ROS 2's name rules).
NODE_NAME = "depthguard"
NODE_NAMESPACE = "/"
#: rmw_zenoh's QoS of a topic we publish: reliable, volatile, keep last 10 (the fields that differ from its
#: defaults).
DEFAULT_QOS = "::,10:,:,:,,"
#: rmw_zenoh's QoS of a topic we subscribe to: best effort (2), volatile, keep last 10. A best-effort subscription
#: is compatible with every publisher, reliable or best effort, volatile or transient local, so every camera
#: driver counts it (image_transport and realsense-ros publish only while they count a subscriber).
SENSOR_QOS = "2::,10:,:,:,,"
#: zenoh-bridge-ros2dds's QoS text for the DDS reader it creates for a topic we subscribe to: keyless, best effort
#: (0), volatile (0), keep last (0) 10. A best-effort volatile reader matches every writer.
BRIDGE_SENSOR_QOS = ":0:0:0,10"
#: ... and for the DDS writer it creates for a topic we publish: keyless, reliable (1), volatile, keep last 10 (what
#: a ROS 2 publisher's default QoS offers; a reliable writer matches reliable and best-effort readers).
BRIDGE_DEFAULT_QOS = ":1:0:0,10"
#: How the bridge writes a ``/`` inside one chunk of its tokens.
_BRIDGE_SLASH = "\u00a7"

_STORE = None


def type_store():
    """rosbags' type store of ROS 2 Jazzy, with control_msgs/msg/SpeedScalingFactor registered (made once)."""
    global _STORE
    if _STORE is None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.ROS2_JAZZY)
        if "control_msgs/msg/SpeedScalingFactor" not in store.types:
            # control_msgs (ros2_control): the speed scaling joint_trajectory_controller takes, 0 to 1.
            store.register(get_types_from_msg("float64 factor\n", "control_msgs/msg/SpeedScalingFactor"))
        _STORE = store
    return _STORE


def type_name(msgtype: str) -> str:
    """The DDS type name rmw_zenoh keys a topic with: ``std_msgs/msg/Float64MultiArray`` ->
    ``std_msgs::msg::dds_::Float64MultiArray_``."""
    package, kind, name = _parts(msgtype)
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(msgtype: str) -> str:
    """``RIHS01_<64 lowercase hex>``: the ROS 2 type hash of ``msgtype`` (``pkg/msg/Name``)."""
    _parts(msgtype)
    store = type_store()
    if msgtype not in store.types:
        raise InputError(f"unknown message type {msgtype!r}", field="type")
    return store.hash_rihs01(msgtype)


def _parts(msgtype: str) -> tuple[str, str, str]:
    parts = msgtype.split("/") if isinstance(msgtype, str) else []
    if len(parts) != 3 or not all(re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", p) for p in parts):
        raise InputError(f"a message type is pkg/msg/Name, got {msgtype!r}", field="type")
    return parts[0], parts[1], parts[2]


def ros_name(topic: str) -> str:
    """``topic`` as the absolute name ROS 2 gives it in the node ``/depthguard``: ``~`` and ``~/x`` expand to
    ``/depthguard`` and ``/depthguard/x``, a relative ``x/y`` to ``/x/y``; a trailing slash is dropped.
    Substitutions (``{node}``) and anything that is not a ROS 2 topic name are refused with an :class:`InputError`
    naming the topic."""
    if not isinstance(topic, str) or not _TOPIC.fullmatch(topic) or "//" in topic:
        raise InputError(f"not a ROS 2 topic name: {topic!r} (letters, digits and underscores between slashes; "
                         f"'~' for the node's private names; no substitutions)", field="topic")
    name = topic.rstrip("/") if len(topic) > 1 else topic
    if name.startswith("~"):
        node = NODE_NAMESPACE.rstrip("/") + "/" + NODE_NAME
        return node + name[1:]
    return name if name.startswith("/") else NODE_NAMESPACE.rstrip("/") + "/" + name


def _check_topic(topic: str) -> str:
    return ros_name(topic).strip("/")


def data_key(topic: str, msgtype: str, layout: str = "rmw_zenoh", domain: int = 0, distro: str = "jazzy") -> str:
    """The zenoh key a message of ``msgtype`` on ``topic`` is published at, in ``layout`` (and, for rmw_zenoh, the
    ``distro``'s hash style: :func:`hash_of`)."""
    name = _check_topic(topic)
    if layout == "bridge":
        return name
    _check_layout(layout)
    return f"{_check_domain(domain)}/{name}/{type_name(msgtype)}/{hash_of(msgtype, distro)}"


def hash_of(msgtype: str, distro: str = "jazzy") -> str:
    """What rmw_zenoh writes for ``msgtype``'s hash in keys and tokens: its RIHS01 hash on Jazzy and later,
    ``TypeHashNotSupported`` on Humble."""
    if distro not in DISTROS:
        raise InputError(f"distro must be one of {', '.join(DISTROS)}, got {distro!r}", field="distro")
    return type_hash(msgtype) if distro == "jazzy" else HUMBLE_HASH


def distros_of(tokens) -> set:
    """The hash styles (:data:`DISTROS`) that the rmw_zenoh liveliness keys ``tokens`` (an iterable of str) use: a
    peer's publishers and subscriptions say which it speaks."""
    found = set()
    for key in tokens:
        token = parse_liveliness_key(key)
        if token is not None and token.hash is not None:
            found.add("humble" if token.hash == HUMBLE_HASH else "jazzy" if token.hash.startswith("RIHS") else "?")
    return found


def subscription_key(topic: str, msgtype: str, layout: str = "rmw_zenoh", domain: int = 0) -> str:
    """The key expression a subscriber of ``topic`` declares: rmw_zenoh's with any hash (``*``), so that a
    publisher of another version of the type is heard, and warned about (:func:`key_type_hash`)."""
    name = _check_topic(topic)
    if layout == "bridge":
        return name
    _check_layout(layout)
    return f"{_check_domain(domain)}/{name}/{type_name(msgtype)}/*"


def key_type_hash(key: str) -> str | None:
    """The type hash a sample's rmw_zenoh key carries (its last chunk), None when it holds none."""
    last = str(key).rsplit("/", 1)[-1]
    return last if last.startswith("RIHS") else None


def _check_layout(layout: str) -> None:
    if layout not in LAYOUTS:
        raise InputError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}", field="layout")


def _check_domain(domain) -> int:
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
        raise InputError(f"a ROS domain id is a whole number in [0, 232], got {domain!r}", field="domain")
    return domain


@dataclass(frozen=True)
class Attachment:
    """rmw_zenoh's attachment of one sample: sequence number (from 1), source time (nanoseconds since the epoch)
    and the publisher's 16-byte gid."""

    sequence: int
    source_ns: int
    gid: bytes


def attachment_bytes(sequence: int, source_ns: int, gid: bytes) -> bytes:
    """The 33 bytes of rmw_zenoh's attachment."""
    if len(gid) != _GID_SIZE:
        raise InputError(f"a publisher gid is {_GID_SIZE} bytes, got {len(gid)}", field="gid")
    return _ATTACHMENT.pack(sequence, source_ns, _GID_SIZE) + bytes(gid)


def parse_attachment(data: bytes | None) -> Attachment | None:
    """The attachment of an rmw_zenoh sample, None when it has none or it is not one (a bridge's sample)."""
    if data is None or len(data) != _ATTACHMENT.size + _GID_SIZE:
        return None
    sequence, source_ns, size = _ATTACHMENT.unpack_from(data)
    if size != _GID_SIZE:
        return None
    return Attachment(sequence, source_ns, bytes(data[_ATTACHMENT.size:]))


def _mangle(name: str) -> str:
    return name.replace("/", "%")


def _demangle(name: str) -> str:
    return name.replace("%", "/")


def liveliness_key(zid: str, entity: int, kind: str, node: str, topic: str | None = None, msgtype: str | None = None,
                   domain: int = 0, namespace: str = "/", qos: str = DEFAULT_QOS, node_id: int = 0,
                   enclave: str = "/", distro: str = "jazzy") -> str:
    """rmw_zenoh's liveliness token of a node (``kind`` ``"NN"``), a publisher (``"MP"``) or a subscriber
    (``"MS"``) of ``topic`` carrying ``msgtype``; ``zid``: the zenoh session's id (hex)."""
    if kind not in _KINDS[:3]:
        raise InputError(f"an entity kind is NN, MP or MS, got {kind!r}", field="kind")
    head = [ "@ros2_lv", str(_check_domain(domain)), zid, str(node_id), str(entity), kind, _mangle(enclave),
            _mangle(namespace), node]
    if kind == "NN":
        return "/".join(head)
    return "/".join(head + [_mangle(ros_name(topic)), type_name(msgtype), hash_of(msgtype, distro), qos])


def bridge_liveliness_key(zid: str, kind: str, topic: str, msgtype: str, qos: str | None = None) -> str:
    """zenoh-bridge-ros2dds's liveliness token announcing a route of ``kind`` ``"MP"`` (a publisher of ``topic`` on
    the zenoh side: the bridge makes a DDS writer) or ``"MS"`` (a subscriber: the bridge makes a DDS reader), with
    ``msgtype`` and ``qos`` (default :data:`BRIDGE_DEFAULT_QOS` for MP, :data:`BRIDGE_SENSOR_QOS` for MS);
    ``zid``: the zenoh session's id (hex). The bridge's own namespace is taken as ``/``."""
    if kind not in ("MP", "MS"):
        raise InputError(f"a bridge route is MP or MS, got {kind!r}", field="kind")
    _parts(msgtype)
    qos = (BRIDGE_DEFAULT_QOS if kind == "MP" else BRIDGE_SENSOR_QOS) if qos is None else qos
    key = _check_topic(topic).replace("/", _BRIDGE_SLASH)
    return f"@ros2_lv/{zid}/{kind}/{key}/{msgtype.replace('/', _BRIDGE_SLASH)}/{qos}"


def parse_bridge_liveliness_key(key: str) -> tuple[str, str, str, str, str] | None:
    """(zid, kind, topic (absolute), msgtype, qos) of a zenoh-bridge-ros2dds route token (the layout of
    :func:`bridge_liveliness_key`, MP or MS), None when the key is not one."""
    parts = str(key).split("/")
    if len(parts) != 6 or parts[0] != "@ros2_lv" or parts[2] not in ("MP", "MS") or parts[5].count(":") != 3:
        return None
    return (parts[1], parts[2], "/" + parts[3].replace(_BRIDGE_SLASH, "/"), parts[4].replace(_BRIDGE_SLASH, "/"),
            parts[5])


def entity_token(layout: str, zid: str, entity: int, kind: str, topic: str, msgtype: str, domain: int = 0,
                 distro: str = "jazzy") -> str:
    """The liveliness token that announces one of the node's publishers (``kind`` ``"MP"``) or subscriptions
    (``"MS"``) in ``layout``: rmw_zenoh's (:func:`liveliness_key`, QoS :data:`DEFAULT_QOS` or :data:`SENSOR_QOS`) or
    zenoh-bridge-ros2dds's route (:func:`bridge_liveliness_key`, its QoS by kind)."""
    _check_layout(layout)
    if layout == "bridge":
        return bridge_liveliness_key(zid, kind, topic, msgtype)
    return liveliness_key(zid, entity, kind, NODE_NAME, topic, msgtype, domain=domain,
                          qos=SENSOR_QOS if kind == "MS" else DEFAULT_QOS, distro=distro)


@dataclass(frozen=True)
class Token:
    """What an rmw_zenoh liveliness token says (:func:`parse_liveliness_key`): the entity's domain, kind (NN, MP,
    MS, SS, SC), node, and for a topic's entity its topic (absolute), type (``pkg::msg::dds_::Name_``), type hash
    (``RIHS01_...`` or Humble's ``TypeHashNotSupported``) and QoS text."""

    domain: int
    zid: str
    kind: str
    node: str
    topic: str | None = None
    type: str | None = None
    hash: str | None = None
    qos: str | None = None


def parse_liveliness_key(key: str) -> Token | None:
    """The :class:`Token` of an rmw_zenoh liveliness key (the layout of :func:`liveliness_key`), None when the key
    is not one."""
    parts = str(key).split("/")
    if len(parts) < 9 or parts[0] != "@ros2_lv" or not parts[1].isdigit() or parts[5] not in _KINDS:
        return None
    token = Token(int(parts[1]), parts[2], parts[5], parts[8])
    if parts[5] == "NN":
        return token
    if len(parts) < 13:
        return None
    return Token(token.domain, token.zid, token.kind, token.node, _demangle(parts[9]), parts[10], parts[11],
                 parts[12])


def serialize(message, msgtype: str) -> bytes:
    """The CDR bytes (with the encapsulation header) of a rosbags message object."""
    return bytes(type_store().serialize_cdr(message, msgtype))


def deserialize(data: bytes, msgtype: str):
    """A rosbags message object from CDR bytes; :class:`InputError` naming the type when they are not one."""
    if len(data) < 4 or data[:2] not in (b"\x00\x01", b"\x00\x00"):
        raise InputError(f"not a CDR {msgtype} (encapsulation {bytes(data[:4]).hex() or 'none'})", field="payload")
    try:
        return type_store().deserialize_cdr(bytes(data), msgtype)
    except Exception as exc:  # noqa: BLE001 - rosbags' errors for truncated or garbled bytes
        raise InputError(f"not a CDR {msgtype} ({type(exc).__name__}: {str(exc)[:120]})", field="payload") from None
