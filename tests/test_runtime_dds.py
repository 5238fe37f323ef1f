"""The DDS transport on loopback: a LowCmd_ crosses processes with its CRC intact; bad ids and names fail."""

import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="cyclonedds is not installed (pip install cyclonedds==11.0.1)")

from wbmpc.runtime import dds  # noqa: E402
from wbmpc.runtime import messages as m  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]
DISCOVERY_TIMEOUT_S = 10.0


@pytest.fixture
def free_domain() -> int:
    domain = dds.free_domain()
    if domain is None:
        pytest.skip("no DDS domain with free UDP ports found in 100..232")
    return domain


def _busy_command(seq: int) -> m.LowCmd_:
    cmd = m.new_low_cmd()
    m.write_motor_commands(cmd, np.arange(12), *(np.arange(60).reshape(5, 12) * 0.01 + seq))
    cmd.reserve = seq
    return m.stamp_crc(cmd)


def test_low_cmd_crosses_processes_on_loopback_with_its_crc(free_domain):
    # The writer lives in another process, so the sample really goes through lo's UDP sockets (within one
    # process Cyclone delivers locally), after unicast discovery on 127.0.0.1.
    writer_script = textwrap.dedent(
        f"""
        import sys, time
        import numpy as np
        from wbmpc.runtime import dds, messages as m
        with dds.DdsEndpoint({free_domain}, "lo") as ep:
            w = ep.writer(m.LEG_CMD_TOPIC, m.LowCmd_)
            if not ep.wait_for_match(w, {DISCOVERY_TIMEOUT_S}):
                sys.exit(3)
            for seq in range(1, 61):
                cmd = m.new_low_cmd()
                m.write_motor_commands(cmd, np.arange(12), *(np.arange(60).reshape(5, 12) * 0.01 + seq))
                cmd.reserve = seq
                w.write(m.stamp_crc(cmd))
                time.sleep(0.01)
        """
    )
    with dds.DdsEndpoint(free_domain, "lo") as endpoint:
        reader = endpoint.reader(m.LEG_CMD_TOPIC, m.LowCmd_)
        writer = subprocess.Popen([sys.executable, "-c", writer_script], cwd=REPO_ROOT)
        try:
            assert endpoint.wait_for_match(reader, DISCOVERY_TIMEOUT_S), "no writer discovered on lo"
            sample = endpoint.take_latest(reader, timeout_s=DISCOVERY_TIMEOUT_S)
        finally:
            writer.wait(timeout=DISCOVERY_TIMEOUT_S + 5)
    assert writer.returncode == 0
    assert sample is not None, "nothing received on lo"
    assert m.crc_ok(sample)
    assert 1 <= sample.reserve <= 60
    assert m.pack_low_cmd(sample) == m.pack_low_cmd(_busy_command(sample.reserve))


def test_two_endpoints_of_one_process_share_the_domain(free_domain):
    with dds.DdsEndpoint(free_domain) as a, dds.DdsEndpoint(free_domain) as b:
        writer = a.writer(m.LEG_STATE_TOPIC, m.LowState_)
        reader = b.reader(m.LEG_STATE_TOPIC, m.LowState_, depth=4)
        assert a.wait_for_match(writer, DISCOVERY_TIMEOUT_S)
        assert b.take_latest(reader, timeout_s=0.0) is None
        for tick in (1, 2, 3):
            state = m.new_low_state()
            state.tick = tick
            writer.write(m.stamp_crc(state))
        latest = b.take_latest(reader, timeout_s=DISCOVERY_TIMEOUT_S)
        assert latest is not None and m.crc_ok(latest)
        assert latest.tick == 3  # the newest of the queued samples
        assert b.take_latest(reader, timeout_s=0.02) is None  # taken, not read
    assert free_domain not in dds._domains  # released with the last endpoint


@pytest.mark.parametrize("domain", [-1, 233, 1000, 1.0, "1", True, None])
def test_bad_domain_ids_are_refused_before_anything_is_created(domain):
    before = dict(dds._domains)
    with pytest.raises(ValueError, match="domain id must be an integer in 0..232"):
        dds.DdsEndpoint(domain, "lo")
    assert dds._domains == before


def test_an_unknown_interface_is_refused_with_its_name():
    missing = "wbmpc_no_such_if0"
    assert missing not in [name for _, name in socket.if_nameindex()]
    before = dict(dds._domains)
    with pytest.raises(ValueError, match=f"no network interface '{missing}'"):
        dds.DdsEndpoint(dds.DEFAULT_DOMAIN, missing)
    assert dds._domains == before


def test_one_domain_cannot_be_bound_to_two_interfaces(free_domain):
    others = [name for _, name in socket.if_nameindex() if name not in dds.LOOPBACK_INTERFACES]
    if not others:
        pytest.skip("this machine has no network interface besides loopback")
    with dds.DdsEndpoint(free_domain, "lo"):
        with pytest.raises(ValueError, match="already configured on interface 'lo'"):
            dds.DdsEndpoint(free_domain, others[0])


def test_config_binds_only_the_named_interface_and_is_unicast_on_loopback():
    xml = dds.cyclonedds_config(7, "lo")
    assert '<Domain id="7">' in xml and '<NetworkInterface name="lo"/>' in xml
    assert "<AllowMulticast>false</AllowMulticast>" in xml and '<Peer address="127.0.0.1"/>' in xml
    xml = dds.cyclonedds_config(0, "enp3s0")
    assert '<NetworkInterface name="enp3s0"/>' in xml and "AllowMulticast" not in xml


def test_default_domain_is_not_a_unitree_one_and_close_is_final():
    assert dds.DEFAULT_DOMAIN not in (0, 1)
    endpoint = dds.DdsEndpoint()
    assert (endpoint.domain, endpoint.interface) == (dds.DEFAULT_DOMAIN, "lo")
    endpoint.close()
    endpoint.close()
    with pytest.raises(RuntimeError, match="closed"):
        endpoint.writer(m.LEG_CMD_TOPIC, m.LowCmd_)
    with dds.DdsEndpoint() as endpoint, pytest.raises(ValueError, match="depth"):
        endpoint.reader(m.LEG_CMD_TOPIC, m.LowCmd_, depth=0)
