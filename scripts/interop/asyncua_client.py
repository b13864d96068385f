#!/usr/bin/env python3
"""An outside OPC UA client (asyncua, LGPL) against `hartkit serve --opcua`.

Run by crates/hartkit/tests/gateway_opcua.rs as a separate process. Browses
Objects/HART/<loop>/<device>, reads each device's PV with its EngineeringUnits, status
code and source time stamp, subscribes to every PV and counts the data changes, calls
SetDamping on the first device and reads Damping back, calls LoopTest on a multidrop
device (which refuses it), tries to write the Damping variable (always refused), and
prints one JSON object. With --user/--password/--cert it connects to the Basic256Sha256
endpoint, signed and encrypted.

With --access RUNS (a JSON list of runs, each {"name", "cert", "key", "user",
"password", "damping"}, all but "name" optional) it checks access instead, one session
per run in turn: connects (anonymously, or as the user; with a certificate, to the
Basic256Sha256 endpoint), reads the Damping of the device at polling address 1 and its
SetDamping's UserExecutable, calls SetDamping, tries to write the Damping variable,
and when the call went through waits until the device's damping reads back. One JSON
object per run, one line each; "connect" is "ok" or the error that refused it.
"""
import argparse
import asyncio
import json
import time

from asyncua import Client, ua


class Changes:
    def __init__(self):
        self.count = {}

    def datachange_notification(self, node, val, data):
        k = node.nodeid.to_string()
        self.count[k] = self.count.get(k, 0) + 1


def err_name(e):
    """The error's type: asyncua names status errors after the status (BadUserAccessDenied)."""
    return type(e).__name__


async def access_run(url, run, wait):
    out = {"name": run.get("name")}
    c = Client(url, timeout=10)
    try:
        if run.get("cert"):
            await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{run['cert']},{run['key']}")
        if run.get("user"):
            c.set_user(run["user"])
            c.set_password(run.get("password", ""))
        await c.connect()
    except Exception as e:
        out["connect"] = err_name(e)
        out["error"] = str(e)[:400]
        try:
            await c.disconnect()
        except Exception:
            pass
        return out
    out["connect"] = "ok"
    try:
        ns = await c.get_namespace_index("urn:hartkit:gateway:hart")
        hart = await c.nodes.objects.get_child([f"{ns}:HART"])
        target = None
        deadline = time.time() + wait
        while target is None and time.time() < deadline:
            for lp in await hart.get_children():
                for dev in await lp.get_children():
                    pa = await (await dev.get_child([f"{ns}:PollingAddress"])).read_data_value(raise_on_bad_status=False)
                    dmp = await (await dev.get_child([f"{ns}:Damping"])).read_data_value(raise_on_bad_status=False)
                    if pa.Value.Value == 1 and dmp.StatusCode_.is_good():
                        target = (lp, dev)
            if target is None:
                await asyncio.sleep(0.3)
        if target is None:
            out["device"] = None
            return out
        lp, dev = target
        out["device"] = "HART/" + (await lp.read_browse_name()).Name + "/" + (await dev.read_browse_name()).Name
        damping = await dev.get_child([f"{ns}:Damping"])
        out["damping_before"] = await damping.read_value()
        method = await dev.get_child([f"{ns}:SetDamping"])
        out["user_executable"] = (await method.read_attribute(ua.AttributeIds.UserExecutable)).Value.Value
        value = float(run.get("damping", 3.0))
        try:
            await dev.call_method(f"{ns}:SetDamping", ua.Variant(value, ua.VariantType.Float))
            out["set_damping"] = "ok"
        except ua.UaStatusCodeError as e:
            out["set_damping"] = type(e).__name__
        try:
            await damping.write_value(ua.DataValue(ua.Variant(value + 1.0, ua.VariantType.Float)))
            out["write"] = "ok"
        except ua.UaStatusCodeError as e:
            out["write"] = type(e).__name__
        after = await damping.read_value()
        if out["set_damping"] == "ok":
            deadline = time.time() + 20
            while abs(after - value) > 1e-6 and time.time() < deadline:
                await asyncio.sleep(0.2)
                after = await damping.read_value()
        out["damping_after"] = after
    finally:
        await c.disconnect()
    return out


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--devices", type=int, default=4)
    ap.add_argument("--user")
    ap.add_argument("--password")
    ap.add_argument("--cert")
    ap.add_argument("--key")
    ap.add_argument("--damping", type=float, default=2.0)
    ap.add_argument("--wait", type=float, default=60)
    ap.add_argument("--access", help="JSON list of access runs (see above)")
    a = ap.parse_args()
    if a.access:
        for run in json.loads(a.access):
            print(json.dumps(await access_run(a.url, run, a.wait)), flush=True)
        return
    c = Client(a.url, timeout=10)
    if a.cert:
        await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{a.cert},{a.key}")
    if a.user:
        c.set_user(a.user)
        c.set_password(a.password)
    out = {}
    async with c:
        ns = await c.get_namespace_index("urn:hartkit:gateway:hart")
        hart = await c.nodes.objects.get_child([f"{ns}:HART"])
        # Wait until every device is there with a good PV.
        deadline = time.time() + a.wait
        while True:
            devices = []
            for lp in await hart.get_children():
                for dev in await lp.get_children():
                    devices.append((lp, dev))
            good = 0
            for _, dev in devices:
                dv = await (await dev.get_child([f"{ns}:PV"])).read_data_value(raise_on_bad_status=False)
                good += dv.StatusCode_.is_good()
            if (len(devices) >= a.devices and good == len(devices)) or time.time() > deadline:
                break
            await asyncio.sleep(0.5)
        out["devices"] = []
        pvs = []
        for lp, dev in devices:
            pv = await dev.get_child([f"{ns}:PV"])
            pvs.append(pv)
            dv = await pv.read_data_value(raise_on_bad_status=False)
            eu = await (await pv.get_child(["0:EngineeringUnits"])).read_value()
            out["devices"].append({
                "path": "HART/" + (await lp.read_browse_name()).Name + "/" + (await dev.read_browse_name()).Name,
                "pv": dv.Value.Value,
                "status": dv.StatusCode_.name,
                "source_age_s": (time.time() - dv.SourceTimestamp.timestamp()) if dv.SourceTimestamp else None,
                "eu": eu.DisplayName.Text,
                "eu_unit_id": eu.UnitId,
                "eu_namespace": eu.NamespaceUri,
                "tag": await (await dev.get_child([f"{ns}:Tag"])).read_value(),
                "loop_current": await (await dev.get_child([f"{ns}:LoopCurrent"])).read_value(),
                "polling_address": await (await dev.get_child([f"{ns}:PollingAddress"])).read_value(),
                "quality": await (await dev.get_child([f"{ns}:Quality"])).read_value(),
                "type_definition": (await pv.read_type_definition()).to_string(),
            })
        handler = Changes()
        sub = await c.create_subscription(200, handler)
        await sub.subscribe_data_change(pvs)
        deadline = time.time() + 20
        while time.time() < deadline and (not handler.count or max(handler.count.values()) < 3):
            await asyncio.sleep(0.2)
        out["changes"] = max(handler.count.values()) if handler.count else 0
        await sub.delete()
        # The first device found at polling address 1.
        target = None
        for d, (_, dev) in zip(out["devices"], devices):
            if d["polling_address"] == 1:
                target = dev
        try:
            await target.call_method(f"{ns}:SetDamping", ua.Variant(a.damping, ua.VariantType.Float))
            out["set_damping"] = "ok"
        except ua.UaStatusCodeError as e:
            out["set_damping"] = type(e).__name__
        back = None
        deadline = time.time() + 20
        while time.time() < deadline:
            back = await (await target.get_child([f"{ns}:Damping"])).read_value()
            if abs(back - a.damping) < 1e-6:
                break
            await asyncio.sleep(0.2)
        out["damping"] = back
        try:
            await target.call_method(f"{ns}:LoopTest", ua.Variant(12.0, ua.VariantType.Float))
            out["loop_test"] = "ok"
        except ua.UaStatusCodeError as e:
            out["loop_test"] = type(e).__name__
        try:
            await target.call_method(f"{ns}:SetDamping", ua.Variant("x", ua.VariantType.String))
            out["bad_argument"] = "ok"
        except ua.UaStatusCodeError as e:
            out["bad_argument"] = type(e).__name__
        try:
            await (await target.get_child([f"{ns}:Damping"])).write_value(
                ua.DataValue(ua.Variant(a.damping + 1.0, ua.VariantType.Float)))
            out["write"] = "ok"
        except ua.UaStatusCodeError as e:
            out["write"] = type(e).__name__
    print(json.dumps(out))


if __name__ == "__main__":
    asyncio.run(main())
