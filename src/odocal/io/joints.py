"""Which two joints of a ``JointState`` are the wheels the model's ``n_rl`` and ``n_rr`` are: one
rule for the bag reader (:mod:`odocal.io.rosbag`) and the live node (:mod:`odocal.ros2`).

The rule, per side:

1. the joint named by the user (the mapping's ``[wheels] rear_left``/``rear_right``, the node's
   ``left_wheel_joint``/``right_wheel_joint``);
2. else the one joint whose name says rear (or back) and the side (``rear_left_wheel``,
   ``wheel_back_right``), or is the side's short name (``rl``, ``rl_wheel``, ``rl.wheel``,
   ``rl-wheel``, ``r_left_wheel_joint``), and does not say front, steer or caster;
3. else (a robot with two drive wheels: ``left_wheel_joint``, ``wheel_left_joint``) the one
   wheel joint of that side that is not a front, steering or caster wheel.

Where none of these finds exactly one joint (or both sides find the same), the error names the
joints and the setting that picks them.

A car's front wheels (the four-wheel model's ``n_fl``, ``n_fr``; :func:`front_wheel_joints`),
per side: the joint named by the user (``[wheels] front_left``/``front_right``), else the one
joint whose name says front and the side (``front_left_wheel``, ``wheel_front_right``) or is the
side's short name (``fl``, ``fl_wheel``, ``f_left_wheel_joint``), and does not say steer or
caster (a steering joint turns the wheel about its vertical axis; it does not roll it). Where the
names do not give one such joint on each side, the log is read without front wheels (a robot's
casters, a tricycle's one front wheel: what read before still reads); joints the user named
that are not there, or one named front side without the other, are errors.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

#: Joints of a side whose names say rear: rule 2.
_REAR = {"left": re.compile(r"(rear|back).*left|left.*(rear|back)|^r[_.\-]?l(eft)?([_.\-]|$)",
                            re.IGNORECASE),
         "right": re.compile(r"(rear|back).*right|right.*(rear|back)|^r[_.\-]?r(ight)?([_.\-]|$)",
                             re.IGNORECASE)}
#: A side's joint (rule 3) and what is not a driven rear wheel.
_SIDE = {"left": re.compile(r"left|(^|_)l(_|$)", re.IGNORECASE),
         "right": re.compile(r"right|(^|_)r(_|$)", re.IGNORECASE)}
_NOT_DRIVEN = re.compile(r"front|steer|caster|castor", re.IGNORECASE)
_WHEEL = re.compile(r"wheel", re.IGNORECASE)
#: A front wheel's joint of a side.
_FRONT = {"left": re.compile(r"front.*left|left.*front|^f[_.\-]?l(eft)?([_.\-]|$)",
                             re.IGNORECASE),
          "right": re.compile(r"front.*right|right.*front|^f[_.\-]?r(ight)?([_.\-]|$)",
                              re.IGNORECASE)}
_NOT_ROLLING = re.compile(r"steer|caster|castor", re.IGNORECASE)


def wheel_joints(names: Sequence[str], named: tuple[str, str], *, where: str,
                 setting: Callable[[str], str], error: type[Exception]) -> tuple[int, int]:
    """The indices of the left and right wheel joints in ``names`` by the module's rule.

    ``named``: the joints the user named (left, right; empty where not named). ``where`` starts
    each message (the topic), ``setting(side)`` names what picks a side's joint (``"left"``,
    ``"right"``), ``error`` is the exception raised.
    """
    names = list(names)
    listed = ", ".join(names) or "none"
    found: list[int] = []
    for side, wanted in zip(("left", "right"), named, strict=True):
        if wanted:
            found.append(named_joint(names, wanted, where=where, setting=setting(side),
                                     error=error))
            continue
        rear = [i for i, n in enumerate(names)
                if _REAR[side].search(n) and not _NOT_DRIVEN.search(n)]
        driven = [i for i, n in enumerate(names) if _SIDE[side].search(n)
                  and _WHEEL.search(n) and not _NOT_DRIVEN.search(n)]
        matches = rear or driven
        if len(matches) != 1:
            raise error(f"{where}: cannot tell which joint is the {side} wheel among {listed}; "
                        f"set {setting(side)}")
        found.append(matches[0])
    if found[0] == found[1]:
        raise error(f"{where}: the left and the right wheel are the same joint "
                    f"{names[found[0]]!r}; set {setting('left')} and {setting('right')}")
    return found[0], found[1]


def front_wheel_joints(names: Sequence[str], named: tuple[str, str], *, where: str,
                       setting: Callable[[str], str],
                       error: type[Exception]) -> tuple[int, int] | None:
    """The indices of the front left and right wheel joints in ``names`` by the module's rule,
    or None where the joints hold no pair of them. Arguments as :func:`wheel_joints`'."""
    if any(named):
        if not all(named):
            missing = "right" if named[0] else "left"
            raise error(f"{where}: a front wheel joint is named without the other; "
                        f"set {setting(missing)} too")
        left, right = (named_joint(names, wanted, where=where, setting=setting(side),
                                   error=error)
                       for side, wanted in zip(("left", "right"), named, strict=True))
    else:
        found = [[i for i, n in enumerate(names)
                  if _FRONT[side].search(n) and not _NOT_ROLLING.search(n)]
                 for side in ("left", "right")]
        if any(len(matches) != 1 for matches in found):
            return None
        left, right = found[0][0], found[1][0]
    if left == right:
        raise error(f"{where}: the front left and right wheel are the same joint "
                    f"{names[left]!r}; set {setting('left')} and {setting('right')}")
    return left, right


def named_joint(names: Sequence[str], wanted: str, *, where: str, setting: str,
                error: type[Exception]) -> int:
    """The index of the joint the user named ``wanted`` (by ``setting``) in ``names``; the
    error names the joints where there is none of that name."""
    names = list(names)
    if wanted not in names:
        raise error(f"{where}: no joint named {wanted!r} ({setting}); "
                    f"joints: {', '.join(names) or 'none'}")
    return names.index(wanted)
