"""The ports over real iceoryx2 shared memory (a prefix of its own, removed afterwards):
publish/receive with header stamping, lockstep tick selection, and that iceoryx2 refuses a
payload whose type name or size differs from the service's. Skipped without ``iceoryx2``."""

from __future__ import annotations

import ctypes
import glob
import os
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))

try:
    import iceoryx2 as iox2
except ImportError:  # pragma: no cover
    iox2 = None

from bowden_client import layout, services  # noqa: E402


@unittest.skipIf(iox2 is None, "the iceoryx2 package is not installed (pip install -e clients/python)")
class PortsTest(unittest.TestCase):
    def setUp(self):
        from bowden_client.ports import Ports, Settings

        self.prefix = f"bwpyt{os.getpid()}_"
        self.ports = Ports("pytest", Settings(prefix=self.prefix))

    def tearDown(self):
        self.ports.close()
        self.ports = None
        import gc

        gc.collect()
        for f in glob.glob(f"/dev/shm/{self.prefix}*") + glob.glob(f"/tmp/iceoryx2/**/{self.prefix}*", recursive=True):
            os.remove(f)

    def test_publish_receive_and_tick_selection(self):
        out = self.ports.output(services.MOTOR_COMMAND, layout.MotorCommand)
        inp = self.ports.input(services.MOTOR_COMMAND, layout.MotorCommand, buffer=8)
        wake = self.ports.notifier(services.MOTOR_COMMAND)
        listener = self.ports.listener(services.MOTOR_COMMAND)
        for tick in range(4):
            m = layout.MotorCommand(n_cables=10)
            m.cable_disp_mm[0] = tick + 0.5
            self.assertEqual(out.publish(m, tick=tick, t_origin_ns=1000 + tick), 1)
        self.assertGreaterEqual(wake.notify(), 1)
        self.assertTrue(listener.try_wait())
        first = inp.recv()
        self.assertEqual((first.header.seq, first.header.tick, first.header.t_origin_ns), (0, 0, 1000))
        self.assertEqual(first.cable_disp_mm[0], 0.5)
        # Lockstep: tick 2 skips tick 1; asking for tick 2 again keeps tick 3 for later.
        self.assertEqual(inp.take_tick(2).header.tick, 2)
        self.assertEqual(inp.skipped, 1)
        self.assertIsNone(inp.take_tick(2))
        self.assertEqual(inp.latest().header.tick, 3)
        self.assertIsNone(inp.latest())
        self.assertEqual(out.sent, 4)

    def test_a_mismatched_type_is_refused(self):
        self.ports.output(services.PLANT_STATE, layout.PlantState)

        class PlantState(ctypes.Structure):  # same size, another name
            _fields_ = [("raw", ctypes.c_uint8 * ctypes.sizeof(layout.PlantState))]

        class Renamed(layout.PlantState):  # same layout, another type name
            @classmethod
            def type_name(cls):
                return "bowden::PlantStateV2"

        for wrong in (PlantState, Renamed, layout.MotorCommand):
            with self.subTest(type=wrong.__name__), self.assertRaises(Exception):
                self.ports.input(services.PLANT_STATE, wrong)

    def test_status_service_qos(self):
        st = self.ports.output(services.COMPONENT_STATUS, layout.ComponentStatus)
        # 24 publishers are allowed on the status service (every stage plus the launcher).
        more = [self.ports.output(services.COMPONENT_STATUS, layout.ComponentStatus) for _ in range(23)]
        with self.assertRaises(Exception):
            self.ports.output(services.COMPONENT_STATUS, layout.ComponentStatus)
        s = layout.ComponentStatus(state=layout.ComponentStatus.RUNNING)
        s.set_name("pytest")
        inp = self.ports.input(services.COMPONENT_STATUS, layout.ComponentStatus, 256)
        st.publish(s, tick=7, t_origin_ns=0)
        got = inp.recv()
        self.assertEqual((got.name(), got.header.tick, got.state), ("pytest", 7, 1))
        del more


if __name__ == "__main__":
    unittest.main()
