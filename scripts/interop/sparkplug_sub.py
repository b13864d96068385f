"""An independent Sparkplug B client for hartkit's MQTT publisher tests
(crates/hart-sparkplug/tests/interop.rs): paho-mqtt subscribes to spBv1.0/# and prints
one JSON line per message, its payload decoded with the protobuf package from a
descriptor built here, field by field, from Eclipse Tahu's published
sparkplug_b/sparkplug_b.proto (package org.eclipse.tahu.protobuf, proto2); nothing of
hartkit's Rust code is used. Lines on standard input publish:
  {"topic": T, "metrics": [{"name": ..., "datatype": 11, "boolean_value": true}]}
  {"topic": T, "text": "...", "retain": true}   (STATE JSON, or any bytes as text)
  {"topic": T, "hex": "0aff"}                    (raw bytes)
  {"topic": T, "zeros": 1200000}                 (that many zero bytes)
  "qos": 0 or 1 in any of them (default: 1 when retained, 0 otherwise)
Usage: sparkplug_sub.py PORT CLIENT_ID
"""
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory

F = descriptor_pb2.FieldDescriptorProto
OPT, REP = F.LABEL_OPTIONAL, F.LABEL_REPEATED
T = {"uint32": F.TYPE_UINT32, "uint64": F.TYPE_UINT64, "float": F.TYPE_FLOAT,
     "double": F.TYPE_DOUBLE, "bool": F.TYPE_BOOL, "string": F.TYPE_STRING,
     "bytes": F.TYPE_BYTES}
P = ".org.eclipse.tahu.protobuf.Payload"


def message(parent, name, fields, oneof=None, nested=(), ext=None):
    m = parent.add()
    m.name = name
    if oneof:
        m.oneof_decl.add().name = oneof
    for (fname, num, label, typ, in_oneof) in fields:
        f = m.field.add()
        f.name, f.number, f.label = fname, num, label
        if typ in T:
            f.type = T[typ]
        else:
            f.type, f.type_name = F.TYPE_MESSAGE, typ
        if in_oneof:
            f.oneof_index = 0
    if ext is not None:
        r = m.extension_range.add()
        r.start, r.end = ext, 536870912
    for n in nested:
        n(m.nested_type)
    return m


def ext_msg(name):
    return lambda p: message(p, name, [], ext=1)


def build():
    fd = descriptor_pb2.FileDescriptorProto()
    fd.name = "sparkplug_b.proto"
    fd.package = "org.eclipse.tahu.protobuf"
    fd.syntax = "proto2"
    values = lambda first, ext_type: [  # noqa: E731
        ("int_value", first, OPT, "uint32", True), ("long_value", first + 1, OPT, "uint64", True),
        ("float_value", first + 2, OPT, "float", True), ("double_value", first + 3, OPT, "double", True),
        ("boolean_value", first + 4, OPT, "bool", True), ("string_value", first + 5, OPT, "string", True)]

    def payload(p):
        def template(q):
            def parameter(r):
                message(r, "Parameter", [("name", 1, OPT, "string", False), ("type", 2, OPT, "uint32", False)]
                        + values(3, None) + [("extension_value", 9, OPT, P + ".Template.Parameter.ParameterValueExtension", True)],
                        oneof="value", nested=[ext_msg("ParameterValueExtension")])
            message(q, "Template", [("version", 1, OPT, "string", False), ("metrics", 2, REP, P + ".Metric", False),
                                    ("parameters", 3, REP, P + ".Template.Parameter", False),
                                    ("template_ref", 4, OPT, "string", False), ("is_definition", 5, OPT, "bool", False)],
                    nested=[parameter], ext=6)

        def dataset(q):
            def dsvalue(r):
                message(r, "DataSetValue", values(1, None) + [("extension_value", 7, OPT, P + ".DataSet.DataSetValue.DataSetValueExtension", True)],
                        oneof="value", nested=[ext_msg("DataSetValueExtension")])

            def row(r):
                message(r, "Row", [("elements", 1, REP, P + ".DataSet.DataSetValue", False)], ext=2)
            message(q, "DataSet", [("num_of_columns", 1, OPT, "uint64", False), ("columns", 2, REP, "string", False),
                                   ("types", 3, REP, "uint32", False), ("rows", 4, REP, P + ".DataSet.Row", False)],
                    nested=[dsvalue, row], ext=5)

        def propvalue(q):
            message(q, "PropertyValue", [("type", 1, OPT, "uint32", False), ("is_null", 2, OPT, "bool", False)] + values(3, None)
                    + [("propertyset_value", 9, OPT, P + ".PropertySet", True),
                       ("propertysets_value", 10, OPT, P + ".PropertySetList", True),
                       ("extension_value", 11, OPT, P + ".PropertyValue.PropertyValueExtension", True)],
                    oneof="value", nested=[ext_msg("PropertyValueExtension")])

        def propset(q):
            message(q, "PropertySet", [("keys", 1, REP, "string", False), ("values", 2, REP, P + ".PropertyValue", False)], ext=3)

        def propsetlist(q):
            message(q, "PropertySetList", [("propertyset", 1, REP, P + ".PropertySet", False)], ext=2)

        def metadata(q):
            message(q, "MetaData", [("is_multi_part", 1, OPT, "bool", False), ("content_type", 2, OPT, "string", False),
                                    ("size", 3, OPT, "uint64", False), ("seq", 4, OPT, "uint64", False),
                                    ("file_name", 5, OPT, "string", False), ("file_type", 6, OPT, "string", False),
                                    ("md5", 7, OPT, "string", False), ("description", 8, OPT, "string", False)], ext=9)

        def metric(q):
            message(q, "Metric", [("name", 1, OPT, "string", False), ("alias", 2, OPT, "uint64", False),
                                  ("timestamp", 3, OPT, "uint64", False), ("datatype", 4, OPT, "uint32", False),
                                  ("is_historical", 5, OPT, "bool", False), ("is_transient", 6, OPT, "bool", False),
                                  ("is_null", 7, OPT, "bool", False), ("metadata", 8, OPT, P + ".MetaData", False),
                                  ("properties", 9, OPT, P + ".PropertySet", False)] + values(10, None)
                    + [("bytes_value", 16, OPT, "bytes", True), ("dataset_value", 17, OPT, P + ".DataSet", True),
                       ("template_value", 18, OPT, P + ".Template", True),
                       ("extension_value", 19, OPT, P + ".Metric.MetricValueExtension", True)],
                    oneof="value", nested=[ext_msg("MetricValueExtension")])

        message(p, "Payload", [("timestamp", 1, OPT, "uint64", False), ("metrics", 2, REP, P + ".Metric", False),
                               ("seq", 3, OPT, "uint64", False), ("uuid", 4, OPT, "string", False),
                               ("body", 5, OPT, "bytes", False)],
                nested=[template, dataset, propvalue, propset, propsetlist, metadata, metric], ext=6)

    payload(fd.message_type)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("org.eclipse.tahu.protobuf.Payload"))


Payload = build()
out_lock = threading.Lock()


def emit(obj):
    with out_lock:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


def on_connect(client, userdata, flags, reason_code, properties):
    client.subscribe("spBv1.0/#", qos=1)


def on_subscribe(client, userdata, mid, reason_codes, properties):
    emit({"ready": True, "at": time.time()})


def on_message(client, userdata, msg):
    rec = {"topic": msg.topic, "qos": msg.qos, "retain": bool(msg.retain), "at": time.time()}
    if msg.topic.startswith("spBv1.0/STATE/"):
        rec["text"] = msg.payload.decode("utf-8", "replace")
    else:
        p = Payload()
        try:
            p.ParseFromString(msg.payload)
            rec["payload"] = json_format.MessageToDict(p, preserving_proto_field_name=True)
        except Exception as e:  # not a payload: report it
            rec["error"] = str(e)
    emit(rec)


def main():
    port, client_id = int(sys.argv[1]), sys.argv[2]
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
    c.reconnect_delay_set(min_delay=1, max_delay=1)
    c.on_connect, c.on_subscribe, c.on_message = on_connect, on_subscribe, on_message
    c.connect("127.0.0.1", port, keepalive=5)
    c.loop_start()
    for line in sys.stdin:
        req = json.loads(line)
        if "metrics" in req:
            p = Payload()
            p.timestamp = int(time.time() * 1000)
            for m in req["metrics"]:
                json_format.ParseDict(m, p.metrics.add())
            data = p.SerializeToString()
        elif "hex" in req:
            data = bytes.fromhex(req["hex"])
        elif "zeros" in req:
            data = bytes(req["zeros"])
        else:
            data = req["text"].encode()
        qos = req.get("qos", 1 if req.get("retain") else 0)
        c.publish(req["topic"], data, qos=qos, retain=bool(req.get("retain"))).wait_for_publish(5)
        emit({"published": req["topic"]})
    c.loop_stop()


if __name__ == "__main__":
    main()
