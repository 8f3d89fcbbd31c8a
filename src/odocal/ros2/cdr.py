"""The few fields the node needs, read from a message's serialized bytes (no message objects).

The node subscribes with ``raw=True``: rclpy hands it each message as the bytes DDS carried,
and building the Python message objects (a Header, a Time, Vector3s, Quaternions, lists of
doubles) was most of the node's time per message. The readers here take only what the node
uses (the stamp, two joints' rates or positions, the IMU's rate and acceleration, the
reference's position, yaw and twist) straight from the bytes with :mod:`struct`; the writer
patches a serialized ``nav_msgs/Odometry`` template in place.

The encoding is OMG CDR as ROS 2's middlewares write it: a 4-byte encapsulation header (plain
CDR, XCDR1, big or little endian), then the fields in order, each primitive aligned to its size
counted from the end of that header;
strings as a uint32 length (with the terminating NUL) and the characters; sequences as a uint32
count and the elements. Bytes that are neither raise :class:`CdrError`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import itemgetter
from typing import Any, NamedTuple

#: Encapsulation identifiers (the header's second byte) -> (byte order, largest alignment):
#: plain CDR (XCDR1), big and little endian, as ROS 2's middlewares write ROS messages.
_ENCAPSULATIONS = {0x00: (">", 8), 0x01: ("<", 8)}
_HEADER = 4
#: Doubles in geometry_msgs/PoseWithCovariance: position (3), orientation (4), covariance (36).
_POSE_WITH_COVARIANCE = 7 + 36
#: A builtin_interfaces/Time right after the encapsulation header: sec, nanosec.
_STAMP = [(4, "i"), (8, "I")]


class CdrError(ValueError):
    """Bytes that are not the message the topic should carry."""


class _Cursor:
    """A read position in one message's bytes (alignment counted from the header's end)."""

    __slots__ = ("align", "data", "order", "pos")

    def __init__(self, data: bytes) -> None:
        if len(data) < 16 or data[0] != 0:
            raise CdrError("not CDR: too short or an unknown encapsulation")
        kind = _ENCAPSULATIONS.get(data[1])
        if kind is None:
            raise CdrError(f"encapsulation 0x{data[1]:02x} is not plain CDR (XCDR1)")
        self.data = data
        self.order, self.align = kind
        self.pos = _HEADER

    def _at(self, size: int) -> int:
        a = min(size, self.align)
        self.pos += (-(self.pos - _HEADER)) % a
        at = self.pos
        self.pos += size
        if self.pos > len(self.data):
            raise CdrError("the message ends early")
        return at

    def u32(self) -> int:
        at = self._at(4)
        return int(struct.unpack_from(self.order + "I", self.data, at)[0])

    def stamp(self) -> tuple[int, int]:
        """A builtin_interfaces/Time: (sec, nanosec)."""
        at = self._at(4)
        self.pos += 4
        sec, nsec = struct.unpack_from(self.order + "iI", self.data, at)
        return int(sec), int(nsec)

    def string(self) -> bytes:
        """A string's characters (without the terminating NUL)."""
        n = self.u32()
        start = self.pos
        self.pos += n
        if self.pos > len(self.data):
            raise CdrError("a string runs past the message's end")
        return bytes(self.data[start:start + max(n - 1, 0)])

    def doubles_at(self, count: int) -> int:
        """The offset of ``count`` doubles in a row (aligned), the cursor moved past them."""
        at = self._at(8)
        self.pos += 8 * (count - 1)
        if self.pos > len(self.data):
            raise CdrError("the message ends early")
        return at

    def double_sequence(self) -> tuple[int, int]:
        """A sequence of doubles: (offset of the first, count)."""
        n = self.u32()
        return (self.doubles_at(n) if n else self.pos), n


class Fixed:
    """One layout of a message type, learned from one message: where the values wanted lie,
    read with one unpack. A message is of the layout where its length, its byte order and
    every field that fixes the layout (``checks``: offset, struct code, value: a string's
    length, a sequence's count, a joint's name) are those learned; ``read`` gives the values
    ``reads`` asks for (offset, struct code), or None for any other message."""

    __slots__ = ("_checked", "_enc", "_length", "_picked", "_unpack", "_values")

    def __init__(self, data: bytes, order: str, checks: Sequence[tuple[int, str, Any]],
                 reads: Sequence[tuple[int, str]]) -> None:
        items = sorted([(at, code, -1 - i) for i, (at, code, _) in enumerate(checks)]
                       + [(at, code, i) for i, (at, code) in enumerate(reads)])
        fmt, pos = order, 0
        for at, code, _ in items:
            fmt += (f"{at - pos}x" if at > pos else "") + code
            pos = at + struct.calcsize("<" + code)
        where = {key: j for j, (_, _, key) in enumerate(items)}
        self._length, self._enc = len(data), data[1]
        self._unpack = struct.Struct(fmt).unpack_from
        # (a tuple of at least two: itemgetter of one index gives the item, not a tuple)
        checked = [where[-1 - i] for i in range(len(checks))]
        self._checked: Any = itemgetter(*checked, *checked) if checks else None
        self._values = tuple(v for _, _, v in checks) * 2
        self._picked = itemgetter(*(where[i] for i in range(len(reads))))

    def read(self, data: bytes) -> Any:
        if len(data) != self._length or data[1] != self._enc:
            return None
        got = self._unpack(data)
        if self._checked is not None and self._checked(got) != self._values:
            return None
        return self._picked(got)


@dataclass(frozen=True)
class Joints:
    """What a ``sensor_msgs/JointState`` says: stamp, joint names, positions and velocities."""

    sec: int
    nanosec: int
    names: tuple[bytes, ...]
    positions: tuple[float, ...]
    velocities: tuple[float, ...]


def joint_state(data: bytes) -> Joints:
    """A ``sensor_msgs/JointState``'s stamp, names, positions and velocities (every field the
    node reads, parsed in full: :class:`JointReader` reads the same per message, faster)."""
    c = _Cursor(data)
    sec, nsec = c.stamp()
    c.string()                                   # header.frame_id
    names = tuple(c.string() for _ in range(c.u32()))
    fmt = c.order + "{}d"
    at, n = c.double_sequence()
    positions = struct.unpack_from(fmt.format(n), data, at) if n else ()
    at, n = c.double_sequence()
    velocities = struct.unpack_from(fmt.format(n), data, at) if n else ()
    return Joints(sec, nsec, names, positions, velocities)


@dataclass(frozen=True)
class _JointLayout:
    """Where the picked joints' values lie in JointState messages of one layout."""

    order: str
    length: int
    fields: struct.Struct            # every length and count field, from offset 12
    values: tuple[int, ...]          # ... as they read in this layout
    names: tuple[tuple[int, bytes], ...]   # the picked joints' names: (offset, characters)
    positions: tuple[int, ...]       # the wheel joints' offsets (-1: none in these messages)
    velocities: tuple[int, ...]
    steering: int                    # the steering joint's position's offset (-1: none)
    quick: Fixed | None              # the stamp, the velocities and the steering (where there are)


#: What a reader is asked to pick from a layout's joint names: the wheel joints' indices (in
#: the order the values are wanted) and the steering joint's (None: no steering).
Pick = Callable[[tuple[str, ...]], tuple[tuple[int, ...], int | None]]


class JointReader:
    """The wheel joints' positions and velocities, and a steering joint's position, from
    JointState bytes, by index into the names.

    ``pick(names)`` says which joints (their indices; names as text), or raises; it is asked
    once per layout of the messages (joint names, their lengths, how many positions and
    velocities). A message of the layout seen last is read with one check of its length and
    count fields and of the picked names' characters; any other is parsed in full.
    """

    def __init__(self, pick: Pick) -> None:
        self._pick = pick
        self._layout: _JointLayout | None = None

    def read(self, data: bytes) -> tuple[int, int, tuple[float, ...] | None,
                                         tuple[float, ...] | None, float | None]:
        """(sec, nanosec, the wheels' positions or None, their velocities or None, the
        steering joint's position or None)."""
        lay = self._layout
        if lay is None or len(data) != lay.length or data[1] != (lay.order == "<") \
                or lay.fields.unpack_from(data, 12) != lay.values \
                or any(data[at:at + len(name)] != name for at, name in lay.names):
            lay = self._layout = self._learn(data)
        sec, nsec = struct.unpack_from(lay.order + "iI", data, 4)
        d = lay.order + "d"

        def values(offsets: tuple[int, ...]) -> tuple[float, ...] | None:
            if offsets[0] < 0:
                return None
            return tuple(struct.unpack_from(d, data, at)[0] for at in offsets)

        steering = (struct.unpack_from(d, data, lay.steering)[0] if lay.steering >= 0
                    else None)
        return sec, nsec, values(lay.positions), values(lay.velocities), steering

    def velocities(self, data: bytes) -> tuple[Any, ...] | None:
        """(sec, nanosec, each wheel's velocity[, the steering's position]) of a message of
        the layout seen last, where it has them; None for any other message (:meth:`read`
        it)."""
        lay = self._layout
        if lay is None or lay.quick is None:
            return None
        return lay.quick.read(data)

    def _learn(self, data: bytes) -> _JointLayout:
        c = _Cursor(data)
        c.stamp()
        fields: list[tuple[int, int]] = []           # (offset, value) of each u32 field

        def u32() -> int:
            value = c.u32()
            fields.append((c.pos - 4, value))
            return value

        def string() -> tuple[int, bytes]:
            n = u32()
            at = c.pos
            c.pos += n
            if c.pos > len(data):
                raise CdrError("a string runs past the message's end")
            return at, bytes(data[at:at + max(n - 1, 0)])

        string()                                          # header.frame_id
        names = [string() for _ in range(u32())]
        wheels, steer = self._pick(tuple(n.decode("utf-8", "replace") for _, n in names))
        offsets = []
        steering = -1
        for kind in ("positions", "velocities"):
            n = u32()
            at = c.doubles_at(n) if n else c.pos
            offsets.append(tuple(at + 8 * i for i in wheels) if n > max(wheels)
                           else (-1,) * len(wheels))
            if kind == "positions" and steer is not None and n > steer:
                steering = at + 8 * steer
        n = u32()                                         # efforts (their count fixes the length)
        if n:
            c.doubles_at(n)
        fmt, pos = c.order, 12
        for at, _ in fields:
            fmt += f"{at - pos}xI"
            pos = at + 4
        velocities = offsets[1]
        picked = tuple(names[i] for i in (*wheels, *(() if steer is None else (steer,))))
        checks = [(at, "I", v) for at, v in fields] + [
            (at, f"{len(name)}s", name) for at, name in picked if name]
        reads = [*_STAMP, *((at, "d") for at in velocities),
                 *(((steering, "d"),) if steering >= 0 else ())]
        quick = (Fixed(data, c.order, checks, reads)
                 if velocities[0] >= 0 and (steer is None or steering >= 0) else None)
        return _JointLayout(order=c.order, length=len(data), fields=struct.Struct(fmt),
                            values=tuple(v for _, v in fields), names=picked,
                            positions=offsets[0], velocities=velocities, steering=steering,
                            quick=quick)


def _fields_at(data: bytes, strings: int, doubles: int) -> tuple[str, int]:
    """The byte order and the offset of the first double after the stamp and ``strings``
    strings, checked to hold ``doubles`` doubles."""
    order, at, _ = _layout(data, strings, doubles)
    return order, at


def _layout(data: bytes, strings: int, doubles: int
            ) -> tuple[str, int, list[tuple[int, str, int]]]:
    """:func:`_fields_at`, and the strings' length fields (offset, value)."""
    if len(data) < 16 or data[0] != 0 or data[1] not in _ENCAPSULATIONS:
        raise CdrError("not CDR: too short or an unknown encapsulation")
    order, align = _ENCAPSULATIONS[data[1]]
    at = 12
    lengths = []
    for _ in range(strings):
        at += (-(at - _HEADER)) % 4
        if at + 4 > len(data):
            raise CdrError("the message ends early")
        n = struct.unpack_from(order + "I", data, at)[0]
        lengths.append((at, "I", n))
        at += 4 + n
    at += (-(at - _HEADER)) % min(8, align)
    if at + 8 * doubles > len(data):
        raise CdrError("the message ends early")
    return order, at, lengths


class Quick:
    """What a reader of one message type takes from a message, read by the layout of the
    last message it learned one from (:class:`Fixed`); ``read`` gives None for bytes that are
    not such a message (the full reader says why)."""

    __slots__ = ("_fixed", "_learn")

    def __init__(self, learn: Callable[[bytes], Fixed]) -> None:
        self._learn = learn
        self._fixed: Fixed | None = None

    def read(self, data: bytes) -> Any:
        fixed = self._fixed
        got = fixed.read(data) if fixed is not None else None
        if got is None:
            try:
                fixed = self._fixed = self._learn(data)
            except CdrError:
                return None
            got = fixed.read(data)
        return got


def _imu_layout(data: bytes) -> Fixed:
    """Where :func:`imu` reads: (sec, nanosec, the angular velocity's x, y, z, the linear
    acceleration's x, y, z)."""
    order, at, lengths = _layout(data, 1, 4 + 9 + 3 + 9 + 3 + 9)
    return Fixed(data, order, lengths,
                 [*_STAMP, *((at + 8 * i, "d") for i in (13, 14, 15, 25, 26, 27))])


def _odometry_layout(data: bytes) -> Fixed:
    """Where :func:`odometry` reads: (sec, nanosec, x, y, qx, qy, qz, qw, vx, vy)."""
    order, at, lengths = _layout(data, 2, _POSE_WITH_COVARIANCE + 6 + 36)
    twist = _POSE_WITH_COVARIANCE
    return Fixed(data, order, lengths,
                 [*_STAMP, *((at + 8 * i, "d") for i in (0, 1, 3, 4, 5, 6, twist, twist + 1))])


def _pose_layout(data: bytes) -> Fixed:
    """Where :func:`pose_with_covariance` reads: (sec, nanosec, x, y, qx, qy, qz, qw)."""
    order, at, lengths = _layout(data, 1, _POSE_WITH_COVARIANCE)
    return Fixed(data, order, lengths,
                 [*_STAMP, *((at + 8 * i, "d") for i in (0, 1, 3, 4, 5, 6))])


def imu_reader() -> Quick:
    """:func:`imu`'s values as one flat tuple, by layout."""
    return Quick(_imu_layout)


def odometry_reader() -> Quick:
    """:func:`odometry`'s values as one flat tuple, by layout."""
    return Quick(_odometry_layout)


def pose_reader() -> Quick:
    """:func:`pose_with_covariance`'s values as one flat tuple, by layout."""
    return Quick(_pose_layout)


def imu(data: bytes) -> tuple[int, int, tuple[float, float, float],
                              tuple[float, float, float]]:
    """A ``sensor_msgs/Imu``'s stamp, angular velocity (x, y, z) and linear acceleration."""
    order, at = _fields_at(data, 1, 4 + 9 + 3 + 9 + 3 + 9)   # orientation, its covariance, ...
    sec, nsec = struct.unpack_from(order + "iI", data, 4)
    fmt = order + "3d"
    return (sec, nsec, struct.unpack_from(fmt, data, at + 8 * 13),
            struct.unpack_from(fmt, data, at + 8 * 25))


class Pose(NamedTuple):
    """A reference pose: stamp, position (x, y), orientation (x, y, z, w) and, where the
    message has one, the twist's linear velocity (x, y) in the child frame."""

    sec: int
    nanosec: int
    x: float
    y: float
    orientation: tuple[float, float, float, float]   # a quaternion (not theta)
    velocity: tuple[float, float] | None = None


def odometry(data: bytes) -> Pose:
    """A ``nav_msgs/Odometry``'s stamp, pose and the twist's linear velocity."""
    order, at = _fields_at(data, 2, _POSE_WITH_COVARIANCE + 6 + 36)   # the pose, the twist
    sec, nsec = struct.unpack_from(order + "iI", data, 4)
    x, y, _, qx, qy, qz, qw = struct.unpack_from(order + "7d", data, at)
    vx, vy = struct.unpack_from(order + "2d", data, at + 8 * _POSE_WITH_COVARIANCE)
    return Pose(sec, nsec, x, y, (qx, qy, qz, qw), (vx, vy))


def pose_with_covariance(data: bytes) -> Pose:
    """A ``geometry_msgs/PoseWithCovarianceStamped``'s stamp and pose."""
    order, at = _fields_at(data, 1, _POSE_WITH_COVARIANCE)
    sec, nsec = struct.unpack_from(order + "iI", data, 4)
    x, y, _, qx, qy, qz, qw = struct.unpack_from(order + "7d", data, at)
    return Pose(sec, nsec, x, y, (qx, qy, qz, qw))


class OdometryWriter:
    """A serialized ``nav_msgs/Odometry`` (its frame names fixed) to fill per message.

    ``template`` is one such message as rclpy serializes it on this machine; the fields the
    node sets (the stamp, the pose, the twist, the two covariances) are found in it by the
    layout above and written in place.
    """

    def __init__(self, template: bytes) -> None:
        c = _Cursor(template)
        if c.order != "<" or c.align != 8:
            raise CdrError("the odometry template is not little-endian XCDR1")
        c.stamp()
        c.string()
        first_end = c.pos
        c.string()
        second_end = c.pos
        self._pose = c.doubles_at(_POSE_WITH_COVARIANCE + 6 + 36)
        self._pose_cov = self._pose + 8 * 7
        self._twist = self._pose + 8 * _POSE_WITH_COVARIANCE
        self._twist_cov = self._twist + 8 * 6
        self.buffer = bytearray(template)
        # the alignment after each frame name zeroed (a serializer may leave whatever its
        # buffer held there): the same message is the same bytes, whoever made the template
        pad = first_end + (-(first_end - _HEADER)) % 4
        self.buffer[first_end:pad] = bytes(pad - first_end)
        self.buffer[second_end:self._pose] = bytes(self._pose - second_end)
        # what the node never sets (z, the orientation's x and y; the twist's other four
        # components) is written as the zeros it is in the template: the message is one pack,
        # the constant stretches between the fields it sets given as strings
        if any(template[self._pose + 16:self._pose + 40]) \
                or any(template[self._twist + 8:self._twist + 40]):
            raise CdrError("the odometry template has values where the node writes none")
        tail = len(template) - (self._twist_cov + 8 * 36)
        self._pack = struct.Struct(
            f"<4siI{self._pose - 12}s2d24x2d288sd32x2d272sd{tail}s").pack
        self._constants: tuple[bytes, ...] = ()
        self._keep()

    def covariances(self, pose: Sequence[float], twist: Sequence[float]) -> None:
        """The 6x6 row-major pose and twist covariances (each 36 values)."""
        struct.pack_into("<36d", self.buffer, self._pose_cov, *pose)
        struct.pack_into("<36d", self.buffer, self._twist_cov, *twist)
        self._keep()

    def _keep(self) -> None:
        """The stretches of the buffer between the fields a message sets."""
        buf = bytes(self.buffer)
        cov = self._twist_cov
        header = buf[:4]                # the CDR header's bytes (not theta)
        # the header, then the parts no message changes
        self._constants = (header, buf[12:self._pose], buf[self._pose_cov:self._twist],
                           buf[cov + 8:cov + 8 * 35], buf[cov + 8 * 36:])

    def message(self, sec: int, nanosec: int, x: float, y: float, qz: float, qw: float,
                v: float, w: float, var_v: float, var_w: float) -> bytes:
        """The message for one stamp: pose (x, y, yaw as qz, qw), speed, yaw rate and their
        variances (the twist covariance's (0, 0) and (5, 5))."""
        head, frames, pose_cov, twist_cov, tail = self._constants
        return self._pack(head, sec, nanosec, frames, x, y, qz, qw, pose_cov, v, w, var_v,
                          twist_cov, var_w, tail)
