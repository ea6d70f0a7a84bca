"""The suite's own isolation against real Fast DDS: each test's domain was free when it began, and a
node in it is seen holding it (so the next test skips a domain whose nodes are still shutting down)."""

import os
import time

import pytest
from pipeline_helpers import node_args
from ros_domains import domain_in_use

pytestmark = pytest.mark.graph


def wait_until(condition, what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"{what} within {timeout} s"
        time.sleep(0.1)


def test_a_domain_is_in_use_while_a_node_lives_in_it(processes):
    domain = int(os.environ["ROS_DOMAIN_ID"])
    assert not domain_in_use(domain)
    node = processes.start(node_args("base_node"))
    wait_until(lambda: domain_in_use(domain), f"base_node seen in domain {domain}")
    assert processes.interrupt(node)[0] == 0
    wait_until(lambda: not domain_in_use(domain), f"domain {domain} free again")
