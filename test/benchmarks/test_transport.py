"""The transport bench's figures (delivered ratio, latency percentiles, CPU from /proc, the
report's rows), its deployment profile as Fast DDS reads it, and a short run of the bench."""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from benchmarks import transport
from harness.dds import current_domain, domain_apart

REPO = Path(__file__).resolve().parents[2]
PROFILE = REPO / "config" / "fastdds_large_images.xml"
NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
FULL_HD_RGB8_BYTES = 1920 * 1080 * 3


# --- pure parts ---------------------------------------------------------------------------


def test_delivered_ratio_counts_each_published_stamp_once_and_ignores_strangers():
    published = list(range(1_000, 1_010))
    received = [1_002, 1_003, 1_003, 5, 1_009]  # a duplicate and a stamp from outside
    assert transport.delivered_ratio(published, received) == pytest.approx(3 / 10)
    assert transport.delivered_ratio(published, published[::-1]) == 1.0
    assert transport.delivered_ratio(published, []) == 0.0


def test_a_window_without_frames_has_no_ratio():
    with pytest.raises(ValueError, match="no frame was published"):
        transport.delivered_ratio([], [1, 2])


def test_latencies_are_stamp_to_arrival_of_the_frames_that_arrived():
    published = [1_000_000_000, 2_000_000_000, 3_000_000_000]
    arrivals = {1_000_000_000: 1.010, 3_000_000_000: 3.5, 7: 9.0}
    assert transport.latencies_ms(published, arrivals) == pytest.approx([10.0, 500.0])


def test_percentiles_agree_with_the_standard_library():
    values = [0.3 * ((i * 37) % 101) + 0.01 * i for i in range(257)]
    # statistics' "inclusive" method is the linear interpolation between closest ranks.
    cuts = statistics.quantiles(values, n=100, method="inclusive")
    assert transport.percentiles(values) == pytest.approx([cuts[49], cuts[94]])
    assert transport.percentiles([4.0]) == [4.0, 4.0]
    assert transport.percentiles([]) == [None, None]


def test_cpu_seconds_read_past_a_command_with_spaces_and_parentheses():
    # /proc/<pid>/stat: pid (comm) state ppid ... utime (14th) stime (15th) ...
    fields = ["S", *map(str, range(4, 14)), "250", "150", *map(str, range(16, 52))]
    stat = "4242 (python (a) b) " + " ".join(fields) + "\n"
    assert transport.cpu_seconds(stat, 100) == pytest.approx(4.0)
    assert transport.cpu_percent(10.0, 13.0, 6.0) == pytest.approx(50.0)


def test_cpu_seconds_of_this_process_grow_with_work():
    before = transport.process_cpu_seconds(os.getpid())
    sum(i * i for i in range(2_000_000))
    assert transport.process_cpu_seconds(os.getpid()) > before


def _row(setting: str, receiver: str = "subscriber") -> dict:
    published = [1_000_000_000 + 33_000_000 * i for i in range(30)]
    arrivals = {stamp: stamp / 1e9 + 0.004 + 0.001 * (i % 5) for i, stamp in enumerate(published)}
    del arrivals[published[7]]
    return transport.make_row(
        setting=setting,
        mode="1080p30",
        receiver=receiver,
        published=published,
        received=list(arrivals),
        arrivals=arrivals,
        cpu_publisher_percent=20.0,
        cpu_receiver_percent=30.0,
        load_average=[0.5, 0.6],
    )


def test_a_row_has_the_required_keys_and_survives_json():
    row = json.loads(json.dumps(_row("LARGE_DATA")))
    assert set(transport.REQUIRED_KEYS) <= set(row)
    assert row["mode"] == "1080p30" and row["receiver"] == "subscriber"
    assert row["frames_published"] == 30 and row["frames_delivered"] == 29
    assert row["delivered_ratio"] == pytest.approx(29 / 30)
    # 4 to 8 ms (frame 7 lost), in the published frames' order
    latencies = [4.0 + (i % 5) for i in range(30) if i != 7]
    cuts = statistics.quantiles(latencies, n=100, method="inclusive")
    assert [row["latency_ms_p50"], row["latency_ms_p95"]] == pytest.approx([cuts[49], cuts[94]])
    assert row["load_average"] == [0.5, 0.6]


def test_only_the_recommended_setting_is_marked_for_deployment():
    marked = {name for name in transport.SETTINGS if _row(name)["deployment"]}
    assert marked == {transport.DEPLOYMENT_SETTING}
    assert transport.DEPLOYMENT_SETTING in transport.SETTINGS


def test_the_table_prints_each_row_and_marks_the_deployment_setting():
    lines = transport.table([_row("defaults"), _row(transport.DEPLOYMENT_SETTING, "node")])
    assert len(lines.splitlines()) == 3
    first, second = lines.splitlines()[1:]
    assert "29/30 96.7%" in first and not first.endswith("*")
    assert second.endswith("*") and " node " in second


def test_each_setting_starts_from_no_dds_choice_of_the_caller():
    base = {
        "PATH": "/bin",
        "FASTDDS_DEFAULT_PROFILES_FILE": "/somewhere/fastdds_loopback.xml",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
        "ROS_DOMAIN_ID": "3",
    }
    environments = {
        name: transport.setting_environment(base, setting, 42)
        for name, setting in transport.SETTINGS.items()
    }
    for environment in environments.values():
        assert environment["PATH"] == "/bin" and environment["ROS_DOMAIN_ID"] == "42"
        assert environment["RMW_IMPLEMENTATION"] == "rmw_fastrtps_cpp"
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in environment
    for name in ("defaults", "compressed"):
        assert not set(transport.DDS_VARIABLES) & set(environments[name])
    assert environments["LARGE_DATA"]["FASTDDS_BUILTIN_TRANSPORTS"] == "LARGE_DATA"
    for name in ("shm_profile", "shm_profile_reliable"):
        # Fast DDS 3 reads the first, Fast DDS 2 (Humble, Jazzy) the second.
        for variable in ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
            assert Path(environments[name][variable]) == PROFILE
    assert [n for n, s in transport.SETTINGS.items() if s.compressed] == ["compressed"]
    assert [n for n, s in transport.SETTINGS.items() if s.reliable] == ["shm_profile_reliable"]


def test_a_profile_of_ones_own_is_a_setting_named_by_its_file(tmp_path):
    profile = tmp_path / "segment_8mib.xml"
    profile.write_text(PROFILE.read_text())
    setting = transport.profile_setting(profile)
    assert setting.name == "profile:segment_8mib"
    environment = transport.setting_environment({}, setting, 1)
    assert environment["FASTDDS_DEFAULT_PROFILES_FILE"] == str(profile)
    assert environment["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(profile)
    with pytest.raises(transport.TransportBenchError, match=r"missing\.xml: no such profile"):
        transport.profile_setting(tmp_path / "missing.xml")


def test_interfaces_besides_loopback_are_read_from_proc_net_dev():
    text = (
        "Inter-|   Receive |  Transmit\n"
        " face |bytes    packets|bytes    packets\n"
        "    lo:    3193      29    0\n"
        "  eth0: 1 2 3\n"
        "  ifb0:       0       0\n"
    )
    assert transport.interfaces(text) == ["eth0", "ifb0"]
    assert transport.interfaces(text.split("  eth0")[0]) == []


# --- the deployment profile ---------------------------------------------------------------


def _default_participant(root: ET.Element) -> ET.Element:
    participants = [
        p for p in root.iterfind("f:participant", NS) if p.get("is_default_profile") == "true"
    ]
    assert len(participants) == 1
    return participants[0]


def test_the_deployment_profile_fits_a_full_hd_frame_in_shared_memory_and_hides_no_host():
    root = ET.parse(PROFILE).getroot()
    descriptors = {
        d.findtext("f:transport_id", namespaces=NS): d
        for d in root.iterfind("f:transport_descriptors/f:transport_descriptor", NS)
    }
    rtps = _default_participant(root).find("f:rtps", NS)
    used = [t.text for t in rtps.iterfind("f:userTransports/f:transport_id", NS)]
    kinds = [descriptors[name].findtext("f:type", namespaces=NS) for name in used]
    assert kinds[0] == "SHM"  # shared memory first: the local path for the images
    assert int(descriptors[used[0]].findtext("f:segment_size", namespaces=NS)) > (
        FULL_HD_RGB8_BYTES
    )
    assert "UDPv4" in kinds  # other hosts are reached
    for name in used:
        for allow_list in ("f:interfaceWhiteList", "f:interfaces"):
            assert descriptors[name].find(allow_list, NS) is None, f"{name} is restricted"
    # The loopback test profile is restricted: the check above would see it.
    loopback = ET.parse(REPO / "config" / "fastdds_loopback.xml").getroot()
    assert loopback.find(".//f:interfaceWhiteList", NS) is not None


# A process that creates a participant and a writer and prints the sizes of the Fast DDS
# shared-memory segments it has mapped (its own, with no peer around): fastdds_<id> from
# Fast DDS 3 on, fastrtps_<id> before.
_SEGMENT_PROBE = """
import json, os, re, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("segment_probe")
node.create_publisher(String, "segment_probe", 10)
sizes = {}
for line in open("/proc/self/maps"):
    found = re.search(r"(/dev/shm/fast(dds|rtps)_[0-9a-f]+)$", line.strip())
    if found:
        sizes[found.group(1)] = os.path.getsize(found.group(1))
print(json.dumps(sorted(sizes.values())))
"""


def _segments(profile: Path | None) -> tuple[list[int], str]:
    env = {k: v for k, v in os.environ.items() if k not in transport.DDS_VARIABLES}
    env["ROS_DOMAIN_ID"] = str(domain_apart(current_domain(), 17))  # apart from the run's
    if profile is not None:
        env.update(transport.profile_variables(profile))
    run = subprocess.run(
        [sys.executable, "-c", _SEGMENT_PROBE],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return json.loads(run.stdout.strip().splitlines()[-1]), run.stderr


@pytest.mark.ros
@pytest.mark.skipif(not Path("/dev/shm").is_dir(), reason="no /dev/shm")
def test_fast_dds_reads_the_deployment_profile_and_maps_the_large_segment(tmp_path):
    pytest.importorskip("rclpy")
    sizes, errors = _segments(PROFILE)
    assert not re.search(r"XMLPARSER|XMLPROFILEPARSER", errors), errors
    assert sizes and max(sizes) > FULL_HD_RGB8_BYTES
    # Without the profile the segment is Fast DDS's default, too small for the frame.
    default_sizes, _ = _segments(None)
    assert default_sizes and max(default_sizes) < FULL_HD_RGB8_BYTES
    # A profile Fast DDS cannot read leaves the default segment (Fast DDS 3 also says so).
    broken = tmp_path / "broken.xml"
    broken.write_text(PROFILE.read_text().replace("</segment_size>", "</segment_sise>"))
    broken_sizes, _ = _segments(broken)
    assert broken_sizes and max(broken_sizes) < FULL_HD_RGB8_BYTES


# --- a short run --------------------------------------------------------------------------


# Five settings of 2 s take 25-35 s on two cores (processes start, meet, warm up): more than a
# test of `make test` should, so `make bench-transport` runs it first (ALLO_TRANSPORT_SMOKE=1).
@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.skipif(
    not os.environ.get("ALLO_TRANSPORT_SMOKE"), reason="run by make bench-transport (~30 s)"
)
@pytest.mark.skipif(
    bool(transport.other_interfaces()),
    reason="not in a private network namespace: the defaults would reach other hosts "
    "(make test and make bench-transport run in one)",
)
def test_a_short_run_of_every_setting_writes_a_row_per_setting(tmp_path, capsys):
    pytest.importorskip("rclpy")
    out = tmp_path / "bench_transport.json"
    status = transport.main(
        ["--duration", "2", "--modes", "720p60", "--no-node", "--out", str(out)]
    )
    assert status == 0
    report = json.loads(out.read_text())
    rows = report["rows"]
    assert [row["setting"] for row in rows] == list(transport.SETTINGS)
    for row in rows:
        assert set(transport.REQUIRED_KEYS) <= set(row)
        assert row["mode"] == "720p60" and row["receiver"] == "subscriber"
        assert row["frames_published"] > 0 and 0.0 <= row["delivered_ratio"] <= 1.0
        assert row["cpu_publisher_percent"] > 0
    by_setting = {row["setting"]: row for row in rows}
    # Frames that fit the transport arrive whatever the load; the latency is then measured.
    for name in (transport.DEPLOYMENT_SETTING, "compressed"):
        assert by_setting[name]["frames_delivered"] > 0
        assert by_setting[name]["latency_ms_p50"] is not None
    assert by_setting["compressed"]["message_bytes"] < by_setting["defaults"]["message_bytes"]
    assert [row["deployment"] for row in rows].count(True) == 1
    printed = capsys.readouterr().out
    assert all(name in printed for name in transport.SETTINGS)
