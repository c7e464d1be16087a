"""The PyPI asyncua client against layerwise's OPC UA server (tests/it/plant_opcua.rs).

    opcua_client.py session URL USER PASSWORD   browse, read the layer as it advances, subscribe
                                               to it and to the alarm's events, acknowledge the
                                               alarm (anonymous: refused; USER: accepted)
    opcua_client.py secure URL USER PASSWORD PKI_DIR CERT_DIR
                                               a server beyond loopback: no anonymous or
                                               unencrypted session; a new client certificate is
                                               refused until moved from PKI_DIR/rejected to
                                               PKI_DIR/trusted; then Basic256Sha256 with USER
    opcua_client.py flood URL                  open subscriptions and monitored items beyond the
                                               server's limits; the refusals are counted

Each prints one JSON object on its last line.
"""

import asyncio
import json
import sys
import time

from asyncua import Client, ua
from asyncua.common import events

NAMESPACE = "urn:layerwise:opcua"


async def child(client, ns, *path):
    return await client.nodes.objects.get_child([f"{ns}:{p}" for p in ("Machines",) + path])


class Collect:
    def __init__(self):
        self.values = []
        self.events = []

    def datachange_notification(self, node, val, data):
        self.values.append(val)

    def event_notification(self, event):
        fields = event.get_event_props_as_fields_dict()
        value = lambda name: fields[name].Value if name in fields else None  # noqa: E731
        self.events.append(
            {
                "message": value("Message").Text if value("Message") else "",
                "event_id": value("EventId").hex() if value("EventId") else "",
                "severity": value("Severity"),
                "active": value("ActiveState/Id"),
                "acked": value("AckedState/Id"),
                "retain": value("Retain"),
                "condition": value("ConditionName"),
            }
        )

    def status_change_notification(self, status):
        pass


FIELDS = ["EventId", "EventType", "SourceNode", "SourceName", "Time", "Message", "Severity",
          "ConditionName", "Retain", "ActiveState/Id", "AckedState/Id", "EnabledState/Id"]


async def alarm_filter(condition):
    """The fields of FIELDS, by browse path from BaseEventType (as Part 4 allows), of the events
    of `condition`'s type and its subtypes."""
    evfilter = ua.EventFilter()
    for path in FIELDS:
        op = ua.SimpleAttributeOperand()
        op.TypeDefinitionId = ua.NodeId(ua.ObjectIds.BaseEventType)
        op.BrowsePath = [ua.QualifiedName(p, 0) for p in path.split("/")]
        op.AttributeId = ua.AttributeIds.Value
        evfilter.SelectClauses.append(op)
    # OfType, not asyncua's default (InList of the type's subtypes by EventType): async-opcua
    # 0.17 does not compare node ids in InList (docs/opcua.md).
    element = ua.ContentFilterElement()
    element.FilterOperator = ua.FilterOperator.OfType
    element.FilterOperands.append(ua.LiteralOperand(Value=ua.Variant(condition.nodeid)))
    evfilter.WhereClause = ua.ContentFilter(Elements=[element])
    return evfilter


async def unresolved_fields(sub, client, condition):
    """The fields of asyncua's default AlarmConditionType filter the server cannot resolve
    (docs/opcua.md names them)."""
    evfilter = await events.get_filter_from_event_type([condition])
    params = ua.CreateMonitoredItemsParameters()
    params.SubscriptionId = sub.subscription_id
    params.TimestampsToReturn = ua.TimestampsToReturn.Both
    request = ua.MonitoredItemCreateRequest()
    request.ItemToMonitor = ua.ReadValueId(NodeId=client.nodes.server.nodeid,
                                           AttributeId=ua.AttributeIds.EventNotifier)
    request.MonitoringMode = ua.MonitoringMode.Reporting
    request.RequestedParameters = ua.MonitoringParameters(ClientHandle=999, QueueSize=1,
                                                          Filter=evfilter)
    params.ItemsToCreate = [request]
    results = await client.uaclient.create_monitored_items(params)
    await client.uaclient.delete_monitored_items(ua.DeleteMonitoredItemsParameters(
        SubscriptionId=sub.subscription_id, MonitoredItemIds=[results[0].MonitoredItemId]))
    statuses = results[0].FilterResult.SelectClauseResults or []
    return sorted({"/".join(q.Name for q in c.BrowsePath) or "(ConditionId)"
                   for c, st in zip(evfilter.SelectClauses, statuses) if not st.is_good()})


def acknowledge(alarm, method, event_id, comment):
    return alarm.call_method(method, ua.Variant(event_id, ua.VariantType.ByteString),
                             ua.LocalizedText(comment))


async def outcome(call):
    """"accepted", or the name of the status code a method call was refused with."""
    try:
        await call
        return "accepted"
    except ua.UaStatusCodeError as e:
        return type(e).__name__


async def wait_for(what, check, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        result = await check()
        if result:
            return result
        await asyncio.sleep(0.1)
    raise SystemExit(f"{what}: not within {timeout} s")


async def session(url, user, password):
    out = {}
    async with Client(url=url, timeout=10) as client:
        ns = await client.get_namespace_index(NAMESPACE)
        printer = await child(client, ns, "Printer")
        out["printer_children"] = sorted(
            [(await c.read_browse_name()).Name for c in await printer.get_children()]
        )
        ident = await child(client, ns, "Printer", "Identification")
        out["manufacturer"] = (await (await ident.get_child(f"{ns}:Manufacturer")).read_value()).Text
        out["model"] = (await (await ident.get_child(f"{ns}:Model")).read_value()).Text
        camera = await child(client, ns, "Printer", "Components", "Camera", "Identification")
        out["camera_model"] = (await (await camera.get_child(f"{ns}:Model")).read_value()).Text
        job = await child(client, ns, "Printer", "Production", "ActiveJob")
        out["job_name"] = await (await job.get_child(f"{ns}:Name")).read_value()
        out["job_state"] = await (await job.get_child(f"{ns}:State")).read_value()
        layer = await child(client, ns, "Printer", "Monitoring", "Process", "CurrentLayer")
        # The alarm's condition events, from the start: the fields a SCADA shows.
        collect = Collect()
        sub = await client.create_subscription(100, collect)
        condition = client.get_node(ua.ObjectIds.AlarmConditionType)
        await sub.subscribe_events(client.nodes.server, evfilter=await alarm_filter(condition))
        out["unresolved_fields"] = await unresolved_fields(sub, client, condition)

        # Read the layer as it advances.
        reads = []

        async def advanced():
            value = await layer.read_value()
            if not reads or reads[-1] != value:
                reads.append(value)
            return len(reads) >= 3

        await wait_for("the layer advancing (read)", advanced, 60)
        out["reads"] = reads

        # Subscribe to it.
        await sub.subscribe_data_change(layer)

        async def two_more():
            return len(set(v for v in collect.values if v is not None)) >= 3

        await wait_for("the layer advancing (subscription)", two_more, 60)
        alarm = await child(client, ns, "Printer", "InspectionAlarm")
        active = await alarm.get_child(f"{ns}:Active")

        async def raised():
            return await active.read_value()

        await wait_for("the inspection alarm raised", raised, 120)
        out["subscribed"] = sorted(set(v for v in collect.values if v is not None))
        out["alarm_kind"] = await (await alarm.get_child(f"{ns}:Kind")).read_value()
        out["alarm_layer"] = await (await alarm.get_child(f"{ns}:Layer")).read_value()
        event_id = await (await alarm.get_child(f"{ns}:LastEventId")).read_value()

        async def event_came():
            return any(e["event_id"] == event_id.hex() for e in collect.events)

        try:
            await wait_for("the raise's condition event", event_came, 10)
        except SystemExit as e:
            raise SystemExit(f"{e}; id {event_id.hex()}, events: {collect.events}")
        out["raise_event"] = next(e for e in collect.events if e["event_id"] == event_id.hex())

        # Without a name: refused.
        method = await alarm.get_child(f"{ns}:Acknowledge")
        out["anonymous_ack"] = await outcome(acknowledge(alarm, method, event_id, "anonymous try"))

    # As a user of the users file.
    named = Client(url=url, timeout=10)
    named.set_user(user)
    named.set_password(password)
    async with named:
        ns = await named.get_namespace_index(NAMESPACE)
        alarm = await child(named, ns, "Printer", "InspectionAlarm")
        method = await alarm.get_child(f"{ns}:Acknowledge")
        event_id = await (await alarm.get_child(f"{ns}:LastEventId")).read_value()
        # A stale event id: refused.
        out["stale_ack"] = await outcome(acknowledge(alarm, method, b"not-this-one", "wrong id"))
        await acknowledge(alarm, method, event_id, "checked part 3, build goes on")
        acked = await alarm.get_child(f"{ns}:Acknowledged")

        async def is_acked():
            return await acked.read_value()

        await wait_for("Acknowledged true", is_acked, 10)
        out["acknowledged_by"] = await (await alarm.get_child(f"{ns}:AcknowledgedBy")).read_value()
        out["second_ack"] = await outcome(acknowledge(alarm, method, event_id, "twice"))
    print(json.dumps(out))


async def refused(client):
    try:
        async with client:
            return "connected"
    except Exception as e:  # noqa: BLE001 (the refusal's kind is what is reported)
        return type(e).__name__


async def secure(url, user, password, pki_dir, cert_dir):
    import glob
    import os
    import shutil
    from pathlib import Path

    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    out = {}
    out["anonymous_none"] = await refused(Client(url=url, timeout=10))
    key, cert = Path(cert_dir) / "client-key.pem", Path(cert_dir) / "client-cert.der"
    uri = "urn:layerwise:test-scada"
    await setup_self_signed_certificate(key, cert, uri, "localhost",
                                        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "test scada"})

    async def signed_in(name, secret):
        client = Client(url=url, timeout=10)
        client.application_uri = uri
        if name:
            client.set_user(name)
            client.set_password(secret)
        await client.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
        return client

    out["untrusted"] = await refused(await signed_in(user, password))
    rejected = glob.glob(os.path.join(pki_dir, "rejected", "*"))
    out["rejected_files"] = len(rejected)
    for path in rejected:
        os.makedirs(os.path.join(pki_dir, "trusted"), exist_ok=True)
        shutil.move(path, os.path.join(pki_dir, "trusted", os.path.basename(path)))
    out["trusted_anonymous"] = await refused(await signed_in(None, None))
    out["wrong_password"] = await refused(await signed_in(user, password + "x"))
    client = await signed_in(user, password)
    async with client:
        ns = await client.get_namespace_index(NAMESPACE)
        layer = await child(client, ns, "Printer", "Monitoring", "Process", "CurrentLayer")
        out["layer"] = await layer.read_value()
        out["policy"] = client.security_policy.URI
    print(json.dumps(out))


async def flood(url):
    out = {"subscriptions": 0, "refused_subscriptions": 0, "items": 0, "refused_items": 0}
    async with Client(url=url, timeout=10) as client:
        ns = await client.get_namespace_index(NAMESPACE)
        layer = await child(client, ns, "Printer", "Monitoring", "Process", "CurrentLayer")
        subs = []
        for _ in range(40):
            try:
                subs.append(await client.create_subscription(50, Collect()))
                out["subscriptions"] += 1
            except ua.UaStatusCodeError:
                out["refused_subscriptions"] += 1
        try:
            handles = await subs[0].subscribe_data_change([layer] * 3000)
            for h in handles:
                if isinstance(h, int):
                    out["items"] += 1
                else:
                    out["refused_items"] += 1
        except ua.UaStatusCodeError:
            out["refused_items"] = 3000
        out["layer_after"] = await layer.read_value()
    print(json.dumps(out))


if __name__ == "__main__":
    mode, url = sys.argv[1], sys.argv[2]
    if mode == "session":
        asyncio.run(session(url, sys.argv[3], sys.argv[4]))
    elif mode == "secure":
        asyncio.run(secure(url, *sys.argv[3:7]))
    else:
        asyncio.run(flood(url))
