"""A Python client of bowden's iceoryx2 services.

- :mod:`bowden_client.layout`: ctypes mirrors of every sample (``interfaces/LAYOUT.md``), with
  the iceoryx2 type names the Rust side declares.
- :mod:`bowden_client.services`: service names and QoS (``interfaces/src/services.rs``,
  ``bowden_runtime::ports::qos_for``).
- :mod:`bowden_client.ports`: the iceoryx2 node and ports, opened as bowden opens them
  (needs the ``iceoryx2`` package).
- :mod:`bowden_client.stage`: the launcher's protocol (ready handshake, lockstep ticks, release
  grid, status samples, shutdown) around a step function.

Only :mod:`layout` and :mod:`services` are imported here, so they work without iceoryx2.
"""

from . import layout, services

__all__ = ["layout", "services"]
__version__ = "0.1.0"
