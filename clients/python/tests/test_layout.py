"""The Python mirrors against the Rust side's own statements of them, parsed from the files so
this test fails as soon as the two diverge:

- ``interfaces/LAYOUT.md``: every struct, its size and every field offset;
- ``interfaces/src/lib.rs``: the iceoryx2 type names (``#[type_name(...)]``) and the compile-time
  size/alignment assertions;
- ``interfaces/src/services.rs``: the service names;
- ``components/runtime/src/ports.rs``: the QoS every process opens a service with.

Needs only the standard library: ``python -m unittest discover -s clients/python/tests``.
The repository root is found from this file, or from ``BOWDEN_REPO``.
"""

from __future__ import annotations

import ctypes
import os
import re
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))

from bowden_client import layout, services  # noqa: E402

REPO = os.environ.get("BOWDEN_REPO") or os.path.normpath(os.path.join(HERE, "..", "..", ".."))


def read(rel: str) -> str:
    with open(os.path.join(REPO, rel), encoding="utf-8") as f:
        return f.read()


def layout_sections():
    """{struct name: (size, service or None, [(offset, field name)])} from LAYOUT.md."""
    out = {}
    current = None
    for line in read("interfaces/LAYOUT.md").splitlines():
        m = re.match(r"^##\s+(.*)\((\d+) bytes", line)
        if m:
            names = re.findall(r"\b([A-Z][A-Za-z0-9]+)\b", m.group(1))
            svc = re.search(r"`(bowden/[a-z_]+)`", m.group(1))
            current = names[-1]
            out[current] = (int(m.group(2)), svc.group(1) if svc else None, [])
            continue
        if line.startswith("## "):
            current = None
            continue
        if current is None or not line.startswith("|"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and cells[0].isdigit():  # | offset | field | type | rows
            out[current][2].append((int(cells[0]), cells[1].split()[0]))
            continue
        for c in cells:
            f = re.match(r"^(\d+)\s+([A-Za-z_][\w.]*)", c)
            if f:
                out[current][2].append((int(f.group(1)), f.group(2)))
    return out


class LayoutTest(unittest.TestCase):
    def test_every_struct_of_layout_md_is_mirrored_with_its_size_and_offsets(self):
        sections = layout_sections()
        self.assertEqual(
            sorted(sections), sorted(t.__name__ for t in layout.ALL_TYPES), "LAYOUT.md and layout.py list other types"
        )
        for name, (size, _svc, fields) in sections.items():
            t = getattr(layout, name)
            with self.subTest(type=name):
                self.assertEqual(ctypes.sizeof(t), size, f"{name}: ctypes size vs LAYOUT.md")
                self.assertEqual(layout.SIZES[t], size)
                self.assertTrue(fields, f"{name}: no field offsets parsed from LAYOUT.md")
                ours = {f: getattr(t, f).offset for f, _ in t._fields_}
                self.assertEqual(
                    sorted({o for o, _ in fields}),
                    sorted(set(ours.values())),
                    f"{name}: field offsets of LAYOUT.md vs ctypes {ours}",
                )
                for off, fname in fields:
                    for candidate in (fname, "_" + fname):
                        if candidate in ours:
                            self.assertEqual(ours[candidate], off, f"{name}.{candidate}")

    def test_sizes_alignments_and_type_names_match_the_rust_types(self):
        lib = read("interfaces/src/lib.rs")
        asserts = re.findall(r"size_of::<(\w+)>\(\) == (\d+) && align_of::<\1>\(\) == (\d+)", lib)
        self.assertEqual(len(asserts), len(layout.ALL_TYPES), "compile-time layout assertions in lib.rs")
        for name, size, align in asserts:
            t = getattr(layout, name)
            with self.subTest(type=name):
                self.assertEqual(ctypes.sizeof(t), int(size))
                self.assertEqual(ctypes.alignment(t), int(align))
        names = re.findall(r'#\[type_name\("([^"]+)"\)\]\s*#\[repr\(C\)\]\s*pub struct (\w+)', lib)
        self.assertEqual(len(names), len(layout.ALL_TYPES), "#[type_name] attributes in lib.rs")
        for type_name, struct in names:
            with self.subTest(type=struct):
                self.assertEqual(getattr(layout, struct).type_name(), type_name)

    def test_no_implicit_padding(self):
        for t in layout.ALL_TYPES:
            end = 0
            for f, ft in t._fields_:
                self.assertEqual(getattr(t, f).offset, end, f"{t.__name__}.{f} after a gap")
                end += ctypes.sizeof(ft)
            self.assertEqual(end, ctypes.sizeof(t), f"{t.__name__}: trailing padding")

    def test_component_status_name_round_trip(self):
        s = layout.ComponentStatus()
        s.set_name("plant")
        self.assertEqual(s.name(), "plant")
        s.set_name("x" * 40)
        self.assertEqual(s.name(), "x" * 32)
        c = s.copy()
        s.set_name("other")
        self.assertEqual(c.name(), "x" * 32)


class ServicesTest(unittest.TestCase):
    def test_service_names_match_services_rs(self):
        consts = dict(re.findall(r'pub const (\w+): &str = "([^"]+)";', read("interfaces/src/services.rs")))
        self.assertTrue(consts)
        for const, value in consts.items():
            with self.subTest(service=const):
                self.assertEqual(getattr(services, const), value)
        self.assertEqual(sorted(services.ALL), sorted(consts.values()))
        self.assertEqual(services.qualified("", "bowden/clock"), "bowden/clock")
        self.assertEqual(services.qualified("arm2", "bowden/clock"), "arm2/bowden/clock")

    def test_payload_types_match_layout_md(self):
        for name, (_size, svc, _f) in layout_sections().items():
            if svc and svc != services.RGBD_FRAME:
                self.assertIs(services.PAYLOAD[svc], getattr(layout, name), svc)

    def test_qos_matches_ports_rs(self):
        ports = read("components/runtime/src/ports.rs")
        body = re.search(r"pub fn qos_for\(.*?\n}\n", ports, re.S)
        self.assertIsNotNone(body, "qos_for not found in components/runtime/src/ports.rs")
        body = body.group(0)
        default = dict(re.findall(r"\n\s*(\w+): (\w+),", re.search(r"let mut q = Qos \{(.*?)\};", body, re.S).group(1)))
        fields = ("max_publishers", "max_subscribers", "max_buffer", "history", "safe_overflow", "max_nodes", "max_borrowed")
        self.assertEqual(sorted(default), sorted(fields), "Qos fields")

        def value(v):
            return {"true": True, "false": False}.get(v, None) if not v.isdigit() else int(v)

        arms = {}
        for base, block in re.findall(r'"(\w+)" => \{(.*?)\}', body, re.S):
            arms[base] = dict(re.findall(r"q\.(\w+) = (\w+);", block))
        for base, field, v in re.findall(r'"(\w+)" => q\.(\w+) = (\w+),', body):
            arms[base] = {field: v}
        self.assertIn("component_status", arms)
        for base in list(arms) + ["joint_command", "plant_state"]:
            expected = {f: value(default[f]) for f in fields}
            expected.update({f: value(v) for f, v in arms.get(base, {}).items()})
            with self.subTest(service=base):
                q = services.qos_for("bowden/" + base)
                self.assertEqual({f: getattr(q, f) for f in fields}, expected)
                self.assertEqual(services.qos_for("ns/bowden/" + base), q)
        ev = re.search(r"fn event\(.*?open_or_create", ports, re.S).group(0)
        self.assertEqual(int(re.search(r"max_notifiers\((\d+)\)", ev).group(1)), services.EVENT_QOS.max_notifiers)
        self.assertEqual(int(re.search(r"max_listeners\((\d+)\)", ev).group(1)), services.EVENT_QOS.max_listeners)
        self.assertEqual(int(re.search(r"max_nodes\((\d+)\)", ev).group(1)), services.EVENT_QOS.max_nodes)
        out = re.search(r"pub fn output<.*?create\(\)", ports, re.S).group(0)
        self.assertEqual(int(re.search(r"max_loaned_samples\((\d+)\)", out).group(1)), services.PUBLISHER_MAX_LOANED)

    def test_kinds_match_the_node_declarations(self):
        import glob

        consts = dict(re.findall(r'pub const (\w+): &str = "([^"]+)";', read("interfaces/src/services.rs")))
        files = sorted(glob.glob(os.path.join(REPO, "components/*/src/node.rs")))
        files += [os.path.join(REPO, "components/runtime/src/record.rs"), os.path.join(REPO, "components/bridge/src/lib.rs")]
        kinds = []
        for f in files:
            with open(f, encoding="utf-8") as fh:
                text = fh.read()
            kinds += re.findall(
                r'pub const KIND: NodeKind = NodeKind \{\s*kind: "([\w-]+)",.*?inputs: &\[(.*?)\],\s*outputs: &\[([^\]]*)\]',
                text,
                re.S,
            )
        self.assertEqual(sorted(k for k, _, _ in kinds), sorted(services.KIND_INPUTS), "the node kinds' KIND constants")
        for kind, inputs, outputs in kinds:
            ticks = re.findall(r"InputDecl::new\(services::(\w+),\s*Read::Tick", inputs)
            with self.subTest(kind=kind):
                self.assertEqual(services.KIND_INPUTS[kind], tuple(consts[c] for c in ticks))
                outs = [c.split("::")[-1].strip() for c in outputs.split(",") if c.strip()]
                self.assertEqual(services.KIND_OUTPUTS[kind], tuple(consts[c] for c in outs))

    def test_producers_from_a_pipeline_file(self):
        import tempfile

        self.assertEqual(services.producers("@sim", services.MOTOR_COMMAND), ["actuator"])
        self.assertEqual(services.producers(None, services.PLANT_STATE), ["plant"])
        text = '[runtime]\nmode = "lockstep"\nperiod_us = 1000\n[[node]]\nname = "drive"\nkind = "actuator"\n'
        text += '[[node]]\nname = "old"\nkind = "actuator"\nenabled = false\n'
        with tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False) as f:
            f.write(text)
        try:
            if sys.version_info >= (3, 11):
                self.assertEqual(services.producers(f.name, services.MOTOR_COMMAND), ["drive"])
        finally:
            os.unlink(f.name)


if __name__ == "__main__":
    unittest.main()
