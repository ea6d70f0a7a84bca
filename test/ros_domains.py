"""Which ROS domains a test may take: ROS_DOMAIN_ID 1..100 (above 100, Fast DDS's ports reach into
Linux's ephemeral port range), and whether a participant on this machine holds one now."""

import socket

DOMAINS = 100


def domain_in_use(domain: int) -> bool:
    """A DDS participant on this machine (of another test run, or one still shutting down) holds a
    discovery port of ``domain``: participant k's metatraffic unicast port, 7400 + 250 domain + 10 + 2 k
    (the RTPS port mapping), for the first few k."""
    for participant in range(4):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("", 7410 + 250 * domain + 2 * participant))
            except OSError:
                return True
    return False
