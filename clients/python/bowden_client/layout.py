"""ctypes mirrors of bowden's samples (``interfaces/LAYOUT.md``, ``interfaces/src/lib.rs``).

Every class is a ``ctypes.Structure`` with exactly the fields, order, sizes and alignment of the
``#[repr(C)]`` Rust type, and answers ``type_name()`` with the name the Rust type declares in
``#[type_name("bowden::...")]``: iceoryx2 compares the payload's type name, size and alignment
when a service is opened, so a mismatch is refused instead of read as garbage.

Conventions (as in LAYOUT.md): little-endian, angles in degrees, lengths in mm, times in ns of
CLOCK_MONOTONIC (simulated in lockstep). Arrays are sized for the largest robot
(``MAX_JOINTS``, ``MAX_CABLES``); ``n_joints`` / ``n_cables`` say how many entries are used.

This module needs nothing but the standard library (no iceoryx2), so it can be imported and
tested anywhere.
"""

from __future__ import annotations

import ctypes
import sys

if sys.byteorder != "little":  # pragma: no cover - bowden runs on little-endian machines only
    raise ImportError("bowden samples are little-endian; this machine is big-endian")

MAX_JOINTS = 8
MAX_CABLES = 16
N_MARKERS = 7

u32 = ctypes.c_uint32
u64 = ctypes.c_uint64
f64 = ctypes.c_double


class _Sample(ctypes.Structure):
    """Base of every bowden sample type: the iceoryx2 type name and small helpers."""

    @classmethod
    def type_name(cls) -> str:
        """The iceoryx2 payload type name: ``bowden::<Rust type name>``."""
        return "bowden::" + cls.__name__

    def copy(self):
        """An independent copy (a received sample's memory goes back to iceoryx2)."""
        return type(self).from_buffer_copy(bytes(self))

    def to_dict(self) -> dict:
        """Fields as plain Python values (arrays as lists), for printing and logging."""
        return {name: _plain(getattr(self, name)) for name, _ in self._fields_}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.to_dict()})"


def _plain(v):
    if isinstance(v, _Sample):
        return v.to_dict()
    if isinstance(v, ctypes.Array):
        return [_plain(x) for x in v]
    return v


class SampleHeader(_Sample):
    """First field of every sample (24 bytes)."""

    _fields_ = [
        ("seq", u64),  # per publisher, from 0
        ("tick", u64),  # scheduler tick (lockstep step)
        ("t_origin_ns", u64),  # when the information originated
    ]


class JointTarget(_Sample):
    """q_desired: trajectory → compensator (``bowden/joint_target``, 96 bytes)."""

    FLAG_LAST = 1
    _fields_ = [
        ("header", SampleHeader),
        ("n_joints", u32),
        ("flags", u32),  # bit 0: last target
        ("q_desired_deg", f64 * MAX_JOINTS),
    ]


class JointCommand(_Sample):
    """q_cmd: compensator → actuator (``bowden/joint_command``, 240 bytes)."""

    MODES = {0: "uncalibrated", 1: "paper", 2: "newton"}
    _fields_ = [
        ("header", SampleHeader),  # t_origin_ns copied from the target
        ("n_joints", u32),
        ("mode", u32),  # 0 uncalibrated, 1 paper, 2 newton
        ("q_cmd_deg", f64 * MAX_JOINTS),
        ("q_desired_deg", f64 * MAX_JOINTS),
        ("q_predicted_deg", f64 * MAX_JOINTS),
        ("iterations", u32),
        ("stop_reason", u32),  # 0 none, 1 threshold, 2 max iterations, 3 time budget
        ("compute_ns", u64),
    ]


class MotorCommand(_Sample):
    """Cable displacements: actuator → plant or motor driver (``bowden/motor_command``, 224 bytes)."""

    FLAG_ESTOP = 1
    FLAG_HOLD = 2
    FLAG_CLAMPED = 4
    FLAG_FAULT = 8  # holding on an untrusted robot state
    _fields_ = [
        ("header", SampleHeader),
        ("n_cables", u32),
        ("flags", u32),  # 1 e-stop, 2 hold, 4 clamped, 8 fault
        ("cable_disp_mm", f64 * MAX_CABLES),  # + = pulled in, at the motor end
        ("q_cmd_deg", f64 * MAX_JOINTS),
    ]


class PlantState(_Sample):
    """Ground truth of a (simulated) plant (``bowden/plant_state``, 296 bytes)."""

    _fields_ = [
        ("header", SampleHeader),
        ("n_joints", u32),
        ("n_cables", u32),
        ("t_sim_ns", u64),
        ("q_phy_deg", f64 * MAX_JOINTS),
        ("q_cmd_deg", f64 * MAX_JOINTS),
        ("cable_tip_mm", f64 * MAX_CABLES),
    ]


class RgbdFrameHeader(_Sample):
    """User header of an RGBD frame (``bowden/rgbd_frame``, payload ``[u8]``; 88 bytes)."""

    _fields_ = [
        ("header", SampleHeader),
        ("width", u32),
        ("height", u32),
        ("fx", f64),
        ("fy", f64),
        ("cx", f64),
        ("cy", f64),
        ("depth_unit_mm", f64),
        ("depth_offset", u64),
        ("payload_len", u64),
    ]


class MarkerSet(_Sample):
    """Fitted marker centres in the camera frame (``bowden/marker_set``, 288 bytes)."""

    NAMES = ("r0", "r1", "b0", "r2", "b1", "y0", "g0")
    _fields_ = [
        ("header", SampleHeader),
        ("frame_seq", u64),
        ("centre_cam_mm", (f64 * 3) * N_MARKERS),
        ("residual_mm", f64 * N_MARKERS),
        ("inliers", u32 * N_MARKERS),
        ("valid_mask", u32),
    ]


class JointEstimate(_Sample):
    """Joint angles estimated from the markers (``bowden/joint_estimate``, 184 bytes)."""

    QUALITY_VALID = 0
    QUALITY_PARTIAL = 1
    QUALITY_INVALID = 2
    _fields_ = [
        ("header", SampleHeader),
        ("frame_seq", u64),
        ("n_joints", u32),
        ("quality", u32),
        ("q_phy_deg", f64 * MAX_JOINTS),
        ("joint_valid_mask", u32),
        ("ik_iterations", u32),
        ("ee_pos_base_mm", f64 * 3),
        ("ee_quat_base_wxyz", f64 * 4),
        ("ik_residual_pos_mm", f64),
        ("ik_residual_rot_deg", f64),
    ]


class ComponentStatus(_Sample):
    """Health of one stage (``bowden/component_status``, 128 bytes)."""

    STARTING = 0
    RUNNING = 1
    DEGRADED = 2
    STOPPED = 3
    ESTOP = 4
    FAULT = 5  # safe hold after a fault, latched
    _fields_ = [
        ("header", SampleHeader),
        ("node_name", ctypes.c_uint8 * 32),  # NUL-padded UTF-8
        ("state", u32),
        ("last_fault", u32),  # fault code (interfaces/LAYOUT.md), 0 = none
        ("cycles", u64),
        ("deadline_misses", u64),
        ("rejected_samples", u64),
        ("faults", u64),
        ("latency_p50_ns", u64),
        ("latency_p99_ns", u64),
        ("latency_p999_ns", u64),
        ("latency_max_ns", u64),
    ]

    def set_name(self, name: str) -> None:
        """Writes ``name`` NUL-padded (truncated to 32 bytes)."""
        raw = name.encode("utf-8")[:32]
        ctypes.memset(ctypes.addressof(self.node_name), 0, 32)
        ctypes.memmove(ctypes.addressof(self.node_name), raw, len(raw))

    def name(self) -> str:
        """The stage name as text."""
        raw = bytes(self.node_name)
        return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


class SafetyCommand(_Sample):
    """E-stop latch and release to the actuator (``bowden/safety``, 32 bytes)."""

    ESTOP = 1
    RELEASE = 2
    _fields_ = [
        ("header", SampleHeader),
        ("command", u32),  # 1 e-stop, 2 release
        ("_pad", u32),
    ]


class ClockTick(_Sample):
    """Clock of the launcher (``bowden/clock``, 48 bytes): lockstep ticks, real-time start/stop."""

    _fields_ = [
        ("header", SampleHeader),
        ("t_sim_ns", u64),
        ("dt_ns", u64),
        ("shutdown", u32),  # 1 on the final tick: finish and exit
        ("_pad", u32),
    ]


class ModelUpdate(_Sample):
    """New model weights from an ``adapt`` node (``bowden/model_update``, 336 bytes): the ONNX
    files ``dir/fwd.onnx`` and ``dir/inv.onnx`` and their FNV-1a 64 hashes (0 = not part of
    this update)."""

    _fields_ = [
        ("header", SampleHeader),
        ("generation", u64),
        ("fwd_hash", u64),
        ("inv_hash", u64),
        ("fwd_val_before_deg", f64),
        ("fwd_val_after_deg", f64),
        ("inv_val_before_deg", f64),
        ("inv_val_after_deg", f64),
        ("dir", ctypes.c_uint8 * 256),  # absolute, NUL-padded UTF-8
    ]

    def directory(self) -> str:
        """The directory as text."""
        return bytes(self.dir).split(b"\0", 1)[0].decode("utf-8", "replace")


#: Every sample type, in LAYOUT.md order.
ALL_TYPES = (
    SampleHeader,
    JointTarget,
    JointCommand,
    MotorCommand,
    PlantState,
    RgbdFrameHeader,
    MarkerSet,
    JointEstimate,
    ComponentStatus,
    SafetyCommand,
    ClockTick,
    ModelUpdate,
)

#: Size in bytes of every type, as LAYOUT.md and the Rust compile-time assertions state.
SIZES = {
    SampleHeader: 24,
    JointTarget: 96,
    JointCommand: 240,
    MotorCommand: 224,
    PlantState: 296,
    RgbdFrameHeader: 88,
    MarkerSet: 288,
    JointEstimate: 184,
    ComponentStatus: 128,
    SafetyCommand: 32,
    ClockTick: 48,
    ModelUpdate: 336,
}

for _t, _n in SIZES.items():
    assert ctypes.sizeof(_t) == _n, f"{_t.__name__}: {ctypes.sizeof(_t)} bytes, LAYOUT.md says {_n}"
    assert ctypes.alignment(_t) == 8, f"{_t.__name__}: alignment {ctypes.alignment(_t)}, expected 8"
del _t, _n
