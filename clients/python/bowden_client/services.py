"""bowden's service names and quality of service, as in ``interfaces/src/services.rs`` and
``components/runtime/src/ports.rs`` (``qos_for``, ``PortContext::event``).

Every process opens a service with the same settings; iceoryx2 refuses to open a service whose
existing settings do not satisfy the requested ones, so these numbers must stay equal to the
Rust side's.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import layout

JOINT_TARGET = "bowden/joint_target"
JOINT_COMMAND = "bowden/joint_command"
MOTOR_COMMAND = "bowden/motor_command"
PLANT_STATE = "bowden/plant_state"
RGBD_FRAME = "bowden/rgbd_frame"
MARKER_SET = "bowden/marker_set"
JOINT_ESTIMATE = "bowden/joint_estimate"
COMPONENT_STATUS = "bowden/component_status"
SAFETY = "bowden/safety"
CLOCK = "bowden/clock"
MODEL_UPDATE = "bowden/model_update"

#: Every service name, in ``services::ALL`` order.
ALL = (
    JOINT_TARGET,
    JOINT_COMMAND,
    MOTOR_COMMAND,
    PLANT_STATE,
    RGBD_FRAME,
    MARKER_SET,
    JOINT_ESTIMATE,
    COMPONENT_STATUS,
    SAFETY,
    CLOCK,
    MODEL_UPDATE,
)

#: Payload type of every fixed-size service. ``bowden/rgbd_frame`` carries a ``[u8]`` slice with
#: a :class:`~bowden_client.layout.RgbdFrameHeader` user header instead.
PAYLOAD = {
    JOINT_TARGET: layout.JointTarget,
    JOINT_COMMAND: layout.JointCommand,
    MOTOR_COMMAND: layout.MotorCommand,
    PLANT_STATE: layout.PlantState,
    MARKER_SET: layout.MarkerSet,
    JOINT_ESTIMATE: layout.JointEstimate,
    COMPONENT_STATUS: layout.ComponentStatus,
    SAFETY: layout.SafetyCommand,
    CLOCK: layout.ClockTick,
    MODEL_UPDATE: layout.ModelUpdate,
}


def qualified(namespace: str, name: str) -> str:
    """``name`` under an optional namespace (``"arm2"`` → ``"arm2/bowden/..."``)."""
    return f"{namespace}/{name}" if namespace else name


@dataclass(frozen=True)
class Qos:
    """Publish-subscribe settings of one service (``bowden_runtime::ports::Qos``)."""

    max_publishers: int = 1
    max_subscribers: int = 8
    #: Service-wide upper bound of a subscriber's queue.
    max_buffer: int = 64
    history: int = 0
    #: Newest sample wins when a subscriber's queue is full.
    safe_overflow: bool = True
    max_nodes: int = 24
    max_borrowed: int = 2


def qos_for(service: str) -> Qos:
    """The QoS of a service, by its base name (the namespace does not matter)."""
    base = service.rsplit("/", 1)[-1]
    if base == "component_status":
        return Qos(max_publishers=24, max_subscribers=24, max_buffer=256)
    if base == "safety":
        return Qos(max_publishers=4)
    if base == "rgbd_frame":
        return Qos(max_subscribers=4, max_buffer=4)
    return Qos()


#: A publisher loans at most this many samples at once (``PortContext::output``).
PUBLISHER_MAX_LOANED = 2


@dataclass(frozen=True)
class EventQos:
    """The event service that accompanies every data service (same name): its wake-ups."""

    max_notifiers: int = 32
    max_listeners: int = 32
    max_nodes: int = 32


EVENT_QOS = EventQos()

#: Built-in stage kinds and the services they read (``Read::Tick``: waited for in lockstep) and
#: write, as each kind's ``pub const KIND: NodeKind`` beside its crate declares them
#: (``components/<crate>/src/node.rs``, the registry in ``src/registry.rs``).
KIND_INPUTS = {
    "trajectory": (),
    "compensator": (JOINT_TARGET,),
    "actuator": (JOINT_COMMAND,),
    "plant": (MOTOR_COMMAND,),
    "camera": (PLANT_STATE,),
    "estimator": (RGBD_FRAME,),
    "adapt": (),
    "bridge": (),
    "recorder": (),
}
KIND_OUTPUTS = {
    "trajectory": (JOINT_TARGET,),
    "compensator": (JOINT_COMMAND,),
    "actuator": (MOTOR_COMMAND,),
    "plant": (PLANT_STATE,),
    "camera": (RGBD_FRAME,),
    "estimator": (MARKER_SET, JOINT_ESTIMATE),
    "adapt": (MODEL_UPDATE,),
    "bridge": (),
    "recorder": (),
}


def producers(config_path: str | None, service: str) -> list[str]:
    """Names of the stages that publish ``service`` in a pipeline file (the stages a lockstep
    consumer waits for). Without a readable file (``@sim``, the embedded default), the stage
    named after the built-in kind that produces it."""
    defaults = [k for k, outs in KIND_OUTPUTS.items() if service in outs]
    if not config_path or config_path.startswith("@"):
        return defaults
    try:
        import tomllib  # Python 3.11+
    except ImportError:  # pragma: no cover - older Pythons: the built-in default
        return defaults
    try:
        with open(config_path, "rb") as f:
            cfg = tomllib.load(f)
    except (OSError, ValueError):
        return defaults
    found = []
    for node in cfg.get("node", []):
        if not node.get("enabled", True):
            continue
        name = node.get("name", "")
        kind = node.get("kind", name)
        outs = node.get("outputs", KIND_OUTPUTS.get(kind, ()))
        if kind == "bridge":  # a bridge publishes what it imports from its peer
            outs = node.get("params", {}).get("import", [])
        if service in outs:
            found.append(name)
    return found
