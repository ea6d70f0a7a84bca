"""Every m2h_msgs type crosses from one process to another intact, field by field."""

import json
import sys
from pathlib import Path

import pytest

from m2h_ros.io.msg_defs import msg_files

PROBE = Path(__file__).with_name("msg_probe.py")
pytestmark = pytest.mark.graph


def test_every_message_type_crosses_processes(processes, tmp_path):
    report_file = tmp_path / "report.json"
    receiver = processes.start([sys.executable, str(PROBE), "receive", str(report_file)])
    publisher = processes.start([sys.executable, str(PROBE), "publish"])
    try:
        receiver.wait(timeout=40)
    finally:
        processes.interrupt(publisher)
    report = json.loads(report_file.read_text())
    assert sorted(report) == sorted(msg_files()), "some types never arrived"
    for name, diffs in report.items():
        assert diffs == [], f"{name} arrived changed: {diffs}"
