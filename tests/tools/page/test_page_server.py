"""The page's server without a browser: the token guards viewing (unless --http-public) and
every command, a cross-site request is refused, forms come from the command table and a bad
form is one line; the station's page options are checked at start."""
import json
import subprocess
from urllib.parse import urlsplit

import pytest

from radio.packets.commands import COMMANDS, CommandName
from tests.support.browser import page_address
from tests.support.station_rig import ROOT, python, request, served
from tools.page.forms import forms_html, parse_form
from tools.page.server import parse_http


def command(host, port, headers, name="PING", fields=None):
    return request(host, port, "POST", "/api/command", json.dumps({"name": name, "fields": fields or {}}),
                   {"Content-Type": "application/json", **headers})


def test_viewing_and_commands_need_the_token_and_commands_refuse_other_sites(rig):
    station, host, port, token = served(rig)
    own = f"http://{host}:{port}"
    for path in ("/", "/api/state", "/events", "/capture/1/section"):
        status, _, body = request(host, port, "GET", path)
        assert status == 401 and b"token" in body, (path, status)
    assert request(host, port, "GET", "/?token=wrong")[0] == 401
    status, headers, _ = request(host, port, "GET", f"/?token={token}")
    assert status == 303 and headers["Location"] == "/"
    cookie = headers["Set-Cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and token in cookie
    jar = {"Cookie": cookie.split(";")[0]}
    status, _, body = request(host, port, "GET", "/api/state", headers=jar)
    assert status == 200 and json.loads(body)["authorized"] is True
    # commands: refused without the token, from another site, or as a form post
    assert command(host, port, {})[0] == 403
    status, _, body = command(host, port, {**jar, "Origin": "http://evil.example"})
    assert status == 403 and b"cross-site" in body
    assert command(host, port, {**jar, "Origin": own, "Sec-Fetch-Site": "cross-site"})[0] == 403
    assert command(host, port, jar)[0] == 403  # a cookie without an Origin: not a browser of ours
    status, _, _ = request(host, port, "POST", "/api/command", "name=PING",
                           {**jar, "Origin": own, "Content-Type": "application/x-www-form-urlencoded"})
    assert status == 403
    # accepted with the cookie from the page's own origin, or with the token in its header; no
    # robot hears it, so the answer is still awaited
    status, _, body = command(host, port, {**jar, "Origin": own})
    assert status == 202 and json.loads(body)["waiting"] is True
    status, _, body = command(host, port, {"X-BTF-Token": token}, "GOTO", {"elevation": "70", "azimuth": ""})
    assert status == 202, body
    sent = [e for e in rig.log() if e["kind"] == "command"]
    assert [e["name"] for e in sent] == ["PING", "GOTO"] and sent[1]["args"] == {"elevation": 70.0, "azimuth": 0.0}
    # a bad form is one line naming the problem, and nothing is sent
    status, _, body = command(host, port, {"X-BTF-Token": token}, "GOTO", {"elevation": "700"})
    assert status == 400 and "elevation" in json.loads(body)["error"]
    assert token not in (rig.db.parent / "host.db.log").read_text()  # the token is never logged
    assert rig.stop(station) == 0


def test_a_public_page_is_watched_without_the_token_but_commands_still_need_it(rig):
    station, host, port, token = served(rig, "--http-public")
    status, _, body = request(host, port, "GET", "/api/state")
    state = json.loads(body)
    assert status == 200 and state["authorized"] is False and state["public"] is True
    assert state["snapshot"]["link"]["up"] is False and state["cards"] == []
    status, _, page = request(host, port, "GET", "/")
    assert status == 200 and page.count(b"<form class='command") == len(COMMANDS)
    assert command(host, port, {"Origin": f"http://{host}:{port}"})[0] == 403
    assert command(host, port, {"X-BTF-Token": token + "x"})[0] == 403
    assert rig.stop(station) == 0


def test_page_options_are_checked_before_the_station_starts(rig, tmp_path, host):
    def station(*argv):  # in this process: the checks refuse before any port or database is opened
        code, _, err = host("station", "--port", rig.cable.paths[1], "--db", rig.db, "--key", rig.key, *argv)
        return code, err.strip().splitlines()

    not_fake = tmp_path / "real.toml"
    not_fake.write_text('[hal]\nbody = "real"\n')
    for argv, words in ((["--http", "localhost:http"], "expected PORT or ADDR:PORT"),
                        (["--http", "70000"], "outside 0..65535"),
                        (["--http-public"], "give --http"),
                        (["--http-host", "station.local"], "give --http"),
                        (["--http", "0", "--http-host", "station.local:80"], "expected a host name"),
                        (["--http", "0", "--robot-config", str(not_fake)], "not a fake robot's"),
                        (["--http", "0", "--robot-config", str(tmp_path / "none.toml")], "not found")):
        code, err = station(*argv)
        assert code == 2 and len(err) == 1 and words in err[0], (argv, err)
    taken = rig.station("--http", "127.0.0.1:0")
    url = urlsplit(page_address(rig.where / f"station-{rig.stations}.err"))
    out = subprocess.run([*python("tools.cli"), "station", "--port", rig.cable.paths[0], "--db",
                          str(tmp_path / "other.db"), "--key", str(rig.key), "--http", f"127.0.0.1:{url.port}"],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "cannot listen there" in out.stderr.strip().splitlines()[-1]
    assert rig.stop(taken) == 0


def test_every_command_of_the_table_has_a_form_and_its_fields_parse_as_the_cli_parses_them():
    page = forms_html()
    for name, cmd in COMMANDS.items():
        assert f"data-command='{name.name}'" in page and f">{cmd.cli}</button>" in page
        for arg in cmd.args:
            assert f"name='{arg.key}'" in page
    assert parse_form("SWEEP", {"elevations": "80, 60,40", "azimuths": "0,90", "start": ""}) == (
        CommandName.SWEEP, {"elevations": [80.0, 60.0, 40.0], "azimuths": [0.0, 90.0]})
    assert parse_form("SWEEP", {"start": "90", "stop": "30", "step": "10", "azimuths": "0"})[1]["step"] == 10.0
    assert parse_form("SET", {"key": "sweep.azimuths", "value": "[0, 45]"})[1] == {"key": "sweep.azimuths",
                                                                                 "value": [0, 45]}
    assert parse_form("CAPTURE", {}) == (CommandName.CAPTURE, {})
    for name, fields, words in (("SWEEP", {"azimuths": "0"}, "give start/stop/step or elevations"),
                                ("SWEEP", {"start": "90", "elevations": "80", "azimuths": "0"}, "give"),
                                ("GOTO", {"elevation": "north"}, "goto elevation"),
                                ("GOTO", {"elevation": "95"}, "elevation"),
                                ("GOTO", {"height": "1"}, "no field 'height'"),
                                ("REBOOT_SERVO", {"servo_id": "1.5"}, "servo-id"),
                                ("GOTO", {"azimuth": "10"}, "goto: elevation needed"),
                                ("SELF_DESTRUCT", {}, "unknown command"),
                                ("PING", ["x"], "fields must be an object")):
        with pytest.raises(ValueError, match=words):
            parse_form(name, fields)


def test_the_http_address_defaults_to_this_machine_only():
    assert parse_http("8765") == ("127.0.0.1", 8765)
    assert parse_http("0.0.0.0:80") == ("0.0.0.0", 80)
    assert parse_http("[::1]:0") == ("::1", 0)
