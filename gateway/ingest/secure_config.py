"""zenoh configuration files for a secure deployment: mTLS on every link and access control at the gateway.

The gateway runs as the zenoh router (`--mode router --zenoh-config gateway.json5`): every device and observer is
a client that must present a certificate of the project's CA (scripts/make-certs.sh), and the router's
`access_control` (default deny) matches each link's certificate common name:

- a device (`rod-1`, ...) may publish only its own data keys (`rig/{kind}/{id}/imu|reel|env|truth`), hold only its
  own liveliness token, receive only its own command key and ask only its own `gw/config` entry;
- an `observer` (dashboards, recorders, bench tools) may subscribe to `gw/**` and `rig/**` and query `gw/config/**`,
  never publish;
- nobody but the gateway itself (the router's own session, which the ACL does not filter) publishes commands
  (`rig/*/*/reel/cmd`, `rig/*/*/cmd`) or results and alarms (`gw/**`).

`python -m gateway.ingest.secure_config CERTS OUT --device rod:rod-1 --device ball:ball-1 --listen tls/0.0.0.0:7447`
writes `OUT/gateway.json5`, one `OUT/{id}.json5` per device and `OUT/observer.json5` (JSON is valid JSON5).
Key names are those of zenoh 1.x (`transport/link/tls/*`, `access_control/{rules,subjects,policies}`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from gateway import schemas

# Key suffixes each kind may publish on / receive, from the protocol's topic table.
DATA_TOPICS: dict[str, tuple[str, ...]] = {k: schemas.device_suffixes(k, "device", "simulator") for k in schemas.KINDS}
COMMAND_TOPICS: dict[str, tuple[str, ...]] = {k: schemas.device_suffixes(k, "command") for k in schemas.KINDS}
OBSERVER = "observer"


def _tls(certs: Path, name: str, *, listen: bool) -> dict[str, Any]:
    d = certs / name
    tls: dict[str, Any] = {
        "root_ca_certificate": str(certs / "ca.pem"), "enable_mtls": True,
        "connect_private_key": str(d / "key.pem"), "connect_certificate": str(d / "cert.pem"),
        "verify_name_on_connect": True, "close_link_on_expiration": True,
    }  # fmt: skip
    if listen:
        tls |= {"listen_private_key": str(d / "key.pem"), "listen_certificate": str(d / "cert.pem")}
    return {"transport": {"link": {"tls": tls}}}


def _rule(rule_id: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "messages": messages, "flows": flows, "key_exprs": key_exprs}


def access_control(devices: dict[str, str]) -> dict[str, Any]:
    """The router's `access_control` section for `devices` (id -> kind), default deny (see module docstring)."""
    rules, subjects, policies = [], [], []
    for device_id, kind in sorted(devices.items()):
        schemas.imu_key("rod", device_id)  # raises on an invalid id: it becomes part of key expressions
        base = f"rig/{kind}/{device_id}"
        config = [schemas.config_key(kind, device_id)]
        own = [
            _rule(f"{device_id}-data", ["put"], ["ingress"], [f"{base}/{t}" for t in DATA_TOPICS[kind]]),
            # the router must tell the device that the gateway subscribes (its selectors are wildcards such as
            # rig/*/*/imu): a zenoh 1.x client sends a put only where it knows a subscriber, so without this a
            # device's stream stopped after its first packets. It tells the device nothing but that.
            _rule(f"{device_id}-data-route", ["declare_subscriber"], ["egress"],
                  [f"{base}/{t}" for t in DATA_TOPICS[kind]] + list(schemas.SEL_DEVICE_DATA)),
            _rule(f"{device_id}-token", ["liveliness_token"], ["ingress"], [base]),
            _rule(f"{device_id}-config-ask", ["query"], ["ingress"], config),
            _rule(f"{device_id}-config-answer", ["reply"], ["egress"], config),
        ]
        if COMMAND_TOPICS[kind]:
            cmds = [f"{base}/{t}" for t in COMMAND_TOPICS[kind]]
            own += [_rule(f"{device_id}-cmd-subscribe", ["declare_subscriber"], ["ingress"], cmds),
                    _rule(f"{device_id}-cmd-receive", ["put"], ["egress"], cmds)]  # fmt: skip
        rules += own
        subjects.append({"id": device_id, "cert_common_names": [device_id]})
        policies.append({"id": f"{device_id}-policy", "rules": [r["id"] for r in own], "subjects": [device_id]})
    # An observer only declares subscriptions and asks (ingress); data, replies and tokens flow to it (egress).
    observe = ["gw/**", "rig/**"]
    rules += [
        _rule("observe-ask", ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"],
              ["ingress"], observe),
        _rule("observe-receive", ["put", "delete", "reply", "liveliness_token"], ["egress"], observe),
    ]  # fmt: skip
    subjects.append({"id": OBSERVER, "cert_common_names": [OBSERVER]})
    policies.append({"id": "observer-policy", "rules": ["observe-ask", "observe-receive"], "subjects": [OBSERVER]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}  # fmt: skip


def gateway_config(certs: Path, devices: dict[str, str], listen: list[str]) -> dict[str, Any]:
    """The gateway's config: router, mTLS listener with its `gateway` certificate, the access control."""
    return {"mode": "router", "listen": {"endpoints": listen}, "scouting": {"multicast": {"enabled": False}},
            **_tls(certs, "gateway", listen=True), "access_control": access_control(devices)}  # fmt: skip


def client_config(certs: Path, name: str, connect: list[str]) -> dict[str, Any]:
    """A device's (or the observer's) config: client of the gateway, mTLS with its own certificate."""
    return {"mode": "client", "connect": {"endpoints": connect}, "scouting": {"multicast": {"enabled": False}},
            **_tls(certs, name, listen=False)}  # fmt: skip


def write(certs: Path, out: Path, devices: dict[str, str], listen: list[str], connect: list[str]) -> list[Path]:
    """Write gateway.json5, {id}.json5 per device and observer.json5 into `out`; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    files = {"gateway": gateway_config(certs, devices, listen)}
    files |= {name: client_config(certs, name, connect) for name in [*sorted(devices), OBSERVER]}
    paths = []
    for name, conf in files.items():
        path = out / f"{name}.json5"
        path.write_text(json.dumps(conf, indent=2) + "\n")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m gateway.ingest.secure_config", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("certs", type=Path, help="folder written by scripts/make-certs.sh")
    p.add_argument("out", type=Path, help="where to write the .json5 files")
    p.add_argument("--device", action="append", default=[], metavar="KIND:ID", help="e.g. rod:rod-1; repeatable")
    p.add_argument("--listen", action="append", metavar="ENDPOINT", help="gateway listen endpoint "
                   "(default: tls/0.0.0.0:7447)")  # fmt: skip
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="endpoint clients connect to "
                   "(default: tls/localhost:7447; the name must be in the gateway certificate's SAN)")  # fmt: skip
    a = p.parse_args(argv)
    devices = {}
    for d in a.device:
        kind, _, device_id = d.partition(":")
        if kind not in DATA_TOPICS or not schemas.valid_device_id(device_id):
            p.error(f"--device {d!r}: want KIND:ID with KIND in {', '.join(schemas.KINDS)}")
        devices[device_id] = kind
    for path in write(a.certs, a.out, devices, a.listen or ["tls/0.0.0.0:7447"], a.connect or ["tls/localhost:7447"]):
        print(path)


if __name__ == "__main__":
    main()
