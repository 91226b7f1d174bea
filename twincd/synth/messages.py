"""The messages of a written log (bare MCAP, ros2 profile, or rosbag2 sqlite3), each topic
encoded as CDR (``run_messages``):

- ``/joint_states`` sensor_msgs/msg/JointState every 10 ms: ``joint1``…``joint7``, position,
  velocity, effort. ``header.stamp`` is the nominal sample time; the log time is the stamp plus
  a recorder latency of 0.2–1.0 ms.
- ``/collision_flag`` std_msgs/msg/Bool: ``false`` at the start, then one message at every
  switch change (held until the next; log time = switch time + latency).
- ``/collision_link`` std_msgs/msg/String (contract: Inputs, ground truth for isolation; test logs
  only): beside every ``/collision_flag`` message, with the same log time, the link the press
  touches (``link3``…``link6``) when the switch goes on, ``""`` when it goes off, at the start,
  and for a press that touches nothing.
- ``/twincd/contact`` geometry_msgs/msg/WrenchStamped (ground truth, for isolation work; test
  logs only), while a hand touches: one per joint-state sample (same stamp and log time), plus
  one message with an empty ``frame_id`` and zero wrench at the first sample and at the first
  sample after each contact (hold semantics). ``header.frame_id`` = the Pinocchio body frame touched
  (``link3``…``link6``); the wrench is expressed in that link's frame, about its origin: force =
  the hand's force, torque = p × force. τ_ext = J_LOCAL(q)ᵀ [force; torque], with J the joint
  Jacobian of the link's parent joint (the xArm 7's link frames coincide with its joint frames).
- ``/twincd/contact_point`` geometry_msgs/msg/PointStamped, alongside each contact message: the
  contact point p in the link frame (``header.frame_id`` = link).
"""

from __future__ import annotations

from typing import Any

from twincd.io.cdr import bool_cdr, header, joint_state_cdr, serialize, typestore
from twincd.synth.simulate import SynthRun
from twincd.types import FloatArray

JOINT_TOPIC = "/joint_states"
LABEL_TOPIC = "/collision_flag"
LINK_TOPIC = "/collision_link"
CONTACT_TOPIC = "/twincd/contact"
CONTACT_POINT_TOPIC = "/twincd/contact_point"
JOINT_STATE = "sensor_msgs/msg/JointState"
BOOL = "std_msgs/msg/Bool"
STRING = "std_msgs/msg/String"
WRENCH = "geometry_msgs/msg/WrenchStamped"
POINT = "geometry_msgs/msg/PointStamped"

_Wrench = typestore().types["geometry_msgs/msg/Wrench"]
_WrenchStamped = typestore().types[WRENCH]
_Vector3 = typestore().types["geometry_msgs/msg/Vector3"]
_Point = typestore().types["geometry_msgs/msg/Point"]
_PointStamped = typestore().types[POINT]
_String = typestore().types[STRING]

# every topic with its type, in the order a writer registers them
TOPICS = (
    (JOINT_TOPIC, JOINT_STATE),
    (LABEL_TOPIC, BOOL),
    (LINK_TOPIC, STRING),
    (CONTACT_TOPIC, WRENCH),
    (CONTACT_POINT_TOPIC, POINT),
)


def _contact_cdr(
    stamp_ns: int, link: str, wrench: FloatArray, point: FloatArray
) -> tuple[bytes, bytes]:
    hdr: Any = header(stamp_ns, link)
    w = _WrenchStamped(
        header=hdr,
        wrench=_Wrench(
            force=_Vector3(x=float(wrench[0]), y=float(wrench[1]), z=float(wrench[2])),
            torque=_Vector3(x=float(wrench[3]), y=float(wrench[4]), z=float(wrench[5])),
        ),
    )
    p = _PointStamped(
        header=hdr,
        point=_Point(x=float(point[0]), y=float(point[1]), z=float(point[2])),
    )
    return serialize(w, WRENCH), serialize(p, POINT)


def run_messages(run: SynthRun) -> list[tuple[str, int, bytes]]:
    """Every message of a run (or segment) as (topic, log_time_ns, cdr), sorted by log time
    (stable)."""
    out: list[tuple[str, int, bytes]] = []
    states = joint_state_cdr(run.stamp_ns, run.joint_names, run.position, run.velocity, run.effort)
    for i, data in enumerate(states):
        out.append((JOINT_TOPIC, int(run.log_time_ns[i]), data))
    for when, value in run.label_events:
        out.append((LABEL_TOPIC, when, bool_cdr(value)))
    for when, link in run.link_events:
        out.append((LINK_TOPIC, when, serialize(_String(data=link), STRING)))
    if run.presses or run.contact_start:
        # "nothing touches" at the path's first sample and at the first sample after a contact
        previous: str | None = None if run.contact_start else ""
        for i, link in enumerate(run.contact_link):
            if link or (previous is None or previous):
                wrench, point = _contact_cdr(
                    int(run.stamp_ns[i]), link, run.contact_wrench[i], run.contact_point[i]
                )
                out.append((CONTACT_TOPIC, int(run.log_time_ns[i]), wrench))
                out.append((CONTACT_POINT_TOPIC, int(run.log_time_ns[i]), point))
            previous = link
    out.sort(key=lambda m: m[1])
    return out
