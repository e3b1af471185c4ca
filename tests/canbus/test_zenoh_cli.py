"""`skin run` publishing on Zenoh and `skin view --zenoh` reading it, as a user runs them:
simulated patches, the host and the view in three processes on loopback; the [zenoh]
table's checks (one line naming the field)."""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

from canbus.master.hostconfig import host_config_from_dict
from canbus.master.zenoh_settings import ZenohSettings, zenoh_settings_from_table
from canbus.zenoh.reader import subscribe
from skin.cli import main
from skin.errors import ConfigError
from tests.support.rigs.children import run, spawn
from tests.support.rigs.ports import tcp_port
from tests.support.rigs.waiting import wait_until

SKIN = [sys.executable, "-m", "skin.cli"]


def test_skin_run_publishes_and_skin_view_draws_it(tmp_path: Path, udp_channel: str,
                                                   udp_port: int) -> None:
    port = tcp_port()
    config = tmp_path / "host.toml"
    config.write_text(f"""
[host]
heartbeat_ms = 500
[bus]
interface = "udp_multicast"
channel = "{udp_channel}"
options = {{ port = {udp_port} }}
[[patches]]
node_id = 1
position_m = [0.0, 0.0]
[[patches]]
node_id = 2
position_m = [0.0, 0.05]
[zenoh]
host = "cli-host"
listen = ["tcp/127.0.0.1:{port}"]
""")
    sim = spawn([*SKIN, "sim", "run", "indenter", "--patches", "2", "-i", "udp_multicast",
                 "-c", udp_channel, "--bus-kwargs", f"port={udp_port}"])
    host = spawn([*SKIN, "run", str(config)])
    try:
        line = host.wait_for("zenoh: publishing", timeout=60)
        assert line.startswith(f"zenoh: publishing on canskin/cli-host/** (peer, listen "
                               f"tcp/127.0.0.1:{port}"), line
        endpoint = f"tcp/127.0.0.1:{port}"
        with subscribe(settings=ZenohSettings(connect=(endpoint,))) as sub:
            wait_until(lambda: sub.received >= 20, what="20 samples on Zenoh")
        out = tmp_path / "view.json"
        view = run([*SKIN, "view", "--zenoh", endpoint, "--snapshot", "--seconds", "1.5",
                    "--json", str(out)], timeout=120)
        assert view.returncode == 0, view.stderr
        record = json.loads(out.read_text())
        assert record["figures"]["hosts"] == ["cli-host"] and record["samples"] > 20
        assert set(record["patches"]) == {"1", "2"}
        assert "patch 2" in view.stdout
    finally:
        host.stop(signal.SIGTERM)
        sim.stop(signal.SIGTERM)
    assert host.returncode == 0, host.output()
    host_out = host.stdout()
    assert "zenoh: " in host_out and " samples sent on canskin/cli-host/**, 0 dropped" in host_out


@pytest.mark.parametrize(("table", "field"), [
    ({"mode": "broker"}, "zenoh.mode"),
    ({"listen": ["tcp:127.0.0.1"]}, "zenoh.listen[0]"),
    ({"listen": "tcp/1.2.3.4:7447 "}, "zenoh.listen[0]"),  # no socket: refused
    ({"connect": [7447]}, "zenoh.connect[0]"),
    ({"scouting": "no"}, "zenoh.scouting"),
    ({"host": "arm/left"}, "zenoh.host"),
    ({"host": "*"}, "zenoh.host"),
    ({"prefix": "skin/**"}, "zenoh.prefix"),
    ({"queue_size": 0}, "zenoh.queue_size"),
    ({"stats_period_s": -1}, "zenoh.stats_period_s"),
    ({"tls": {"root_ca_certificate": "missing.pem"}}, "zenoh.tls.root_ca_certificate"),
    ({"tls": {"colour": "red"}}, "zenoh.tls.colour"),
    ({"config_file": "nowhere.json5"}, "zenoh.config_file"),
    ({"options": 3}, "zenoh.options"),
    ({"bogus": 1}, "zenoh.bogus"),
    ("peer", "zenoh"),
])
def test_a_bad_zenoh_table_names_its_field(table: object, field: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as err:
        host_config_from_dict({"patches": [{"node_id": 1}], "zenoh": table}, base=tmp_path)
    assert err.value.field == field


def test_tls_keys_go_in_pairs_and_paths_are_relative_to_the_config(tmp_path: Path) -> None:
    (tmp_path / "host.pem").write_text("x")
    (tmp_path / "host.key").write_text("x")
    with pytest.raises(ConfigError, match="listen_private_key: missing"):
        zenoh_settings_from_table({"tls": {"listen_certificate": "host.pem"}}, base=tmp_path)
    settings = zenoh_settings_from_table(
        {"tls": {"listen_certificate": "host.pem", "listen_private_key": "host.key"}},
        base=tmp_path)
    assert settings.tls["listen_certificate"] == str(tmp_path / "host.pem")


def test_defaults_expose_nothing_beyond_the_machine() -> None:
    config = ZenohSettings().zenoh_config()
    assert json.loads(config.get_json("mode")) == "peer"
    assert json.loads(config.get_json("listen/endpoints")) == [
        "tcp/127.0.0.1:7447"]  # no socket: the default, checked
    assert json.loads(config.get_json("connect/endpoints")) == []
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("adminspace/enabled")) is False
    reader = ZenohSettings().zenoh_config(reader=True)
    assert json.loads(reader.get_json("listen/endpoints")) == []
    assert json.loads(reader.get_json("connect/endpoints")) == [
        "tcp/127.0.0.1:7447"]  # no socket: the default, checked


def test_skin_run_refuses_a_bad_zenoh_table_in_one_line(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    config = tmp_path / "host.toml"
    config.write_text('[bus]\ninterface = "virtual"\n[[patches]]\nnode_id = 1\n'
                      '[zenoh]\nlisten = ["nowhere"]\n')
    assert main(["run", str(config)]) == 1
    err = capsys.readouterr().err
    examples = "tcp/127.0.0.1:7447, tls/host:7447"  # no socket: the message's examples
    assert err == f"skin: error: {config}: zenoh.listen[0]: 'nowhere' is not an endpoint " \
                  f"(PROTOCOL/ADDRESS, e.g. {examples})\n"


def test_skin_view_zenoh_refuses_what_does_not_go_with_it(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["view", "--key", "canskin/**"]) == 1
    assert "--key: goes with --zenoh" in capsys.readouterr().err
    assert main(["view", "run.log", "--zenoh"]) == 1
    assert "--zenoh: reads live samples: no FILE with it" in capsys.readouterr().err
