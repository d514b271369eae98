"""A standard rosbridge client (roslibpy, pinned in .ci/requirements.txt) against a rosbridge v2
server: what odocal's mock must do for any client, checked with a library odocal did not write.

usage: python rosbridge_conformance.py HOST PORT CONTROLLER_NODE

Prints one line per check (PASS/FAIL name -- detail) and exits non-zero on any failure. The
server must publish /odom (nav_msgs/msg/Odometry) at 5 Hz or more and obey /cmd_vel.
"""
import json
import sys
import time

import roslibpy
from roslibpy.comm import RosBridgeProtocol

host, port, ctrl = sys.argv[1], int(sys.argv[2]), sys.argv[3]
results = []


def check(name, ok, detail=""):
    results.append((name, bool(ok)))
    print(("PASS " if ok else "FAIL ") + name + (" -- " + str(detail) if detail else ""), flush=True)


# Every frame the server sends, tapped before roslibpy handles it: roslibpy drops operations it
# has no handler for (status) and raises on a service_response without an id.
frames = []
_on_message = RosBridgeProtocol.on_message


def _tap(self, payload):
    msg = json.loads(payload.decode("utf8"))
    frames.append(msg)
    if msg.get("op") in ("status", "fragment") or (
            msg.get("op") == "service_response" and "id" not in msg):
        return None
    return _on_message(self, payload)


RosBridgeProtocol.on_message = _tap


def since(n, op):
    return [f for f in frames[n:] if f.get("op") == op]


def srv(name, typ, args, timeout=5):
    return roslibpy.Service(ros, name, typ).call(roslibpy.ServiceRequest(args), timeout=timeout)


ros = roslibpy.Ros(host=host, port=port)
ros.run(timeout=10)
try:
    # rosapi: the graph as a client sees it.
    topics = srv("/rosapi/topics", "rosapi_msgs/srv/Topics", {})
    pairs = dict(zip(topics["topics"], topics["types"]))
    check("rosapi/topics lists types", len(topics["types"]) == len(topics["topics"]), pairs)
    check("rosapi/topics has /cmd_vel", "/cmd_vel" in pairs, pairs)
    check("rosapi/topic_type", ros.get_topic_type("/odom") == "nav_msgs/msg/Odometry",
          ros.get_topic_type("/odom"))
    services = ros.get_services()
    check("rosapi/services", ctrl + "/get_parameters" in services, services)
    check("rosapi/nodes", ctrl in ros.get_nodes(), "")
    subs = srv("/rosapi/subscribers", "rosapi_msgs/srv/Subscribers", {"topic": "/cmd_vel"})
    check("rosapi/subscribers", ctrl in subs["subscribers"], subs)
    t = srv("/rosapi/get_time", "rosapi_msgs/srv/GetTime", {})["time"]
    check("rosapi/get_time is the wall clock", abs(t["sec"] + t["nanosec"] * 1e-9 - time.time()) < 5, t)

    # Two subscriptions on one topic; one unsubscribes, the other keeps receiving.
    got_a, got_b, stamps = [], [], []
    a = roslibpy.Topic(ros, "/odom", "nav_msgs/msg/Odometry", throttle_rate=200, queue_length=1)
    b = roslibpy.Topic(ros, "/odom", "nav_msgs/msg/Odometry")
    a.subscribe(lambda m: got_a.append(time.monotonic()))

    def on_b(m):
        got_b.append(time.monotonic())
        s = m["header"]["stamp"]
        stamps.append(s["sec"] + s["nanosec"] * 1e-9)

    b.subscribe(on_b)
    time.sleep(1.5)
    check("two subscriptions both receive", got_a and got_b, (len(got_a), len(got_b)))
    check("header stamps are the wall clock", stamps and abs(stamps[-1] - time.time()) < 5,
          stamps[-1:])
    n = len(frames)
    a.unsubscribe()
    # roslibpy's unsubscribe drops every local callback of the topic: b's is attached again so
    # that what arrives for b's subscription is seen.
    ros.on("/odom", on_b)
    nb = len(got_b)
    time.sleep(1.0)
    check("the other subscription keeps receiving", len(got_b) > nb + 5, len(got_b) - nb)
    b.unsubscribe()
    time.sleep(0.5)
    n = len(frames)
    time.sleep(0.5)
    check("nothing arrives after both unsubscribed", not since(n, "publish"), len(since(n, "publish")))

    # Throttle: one subscription at 200 ms.
    got_c = []
    c = roslibpy.Topic(ros, "/odom", "nav_msgs/msg/Odometry", throttle_rate=200)
    c.subscribe(lambda m: got_c.append(time.monotonic()))
    time.sleep(2.1)
    c.unsubscribe()
    gaps = [y - x for x, y in zip(got_c, got_c[1:])]
    check("throttle_rate 200 ms", len(got_c) >= 5 and min(gaps) > 0.15,
          (len(got_c), [round(g, 3) for g in gaps[:4]]))

    # Publish on the robot's velocity topic (roslibpy advertises first): a zero twist.
    cmd = roslibpy.Topic(ros, "/cmd_vel", "geometry_msgs/msg/Twist")
    n = len(frames)
    cmd.publish(roslibpy.Message({"linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                                  "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}))
    time.sleep(0.3)
    check("publish accepted", not since(n, "status"), since(n, "status"))
    cmd.unadvertise()

    # The controller's parameters, as rcl_interfaces defines the services.
    lst = srv(ctrl + "/list_parameters", "rcl_interfaces/srv/ListParameters", {"prefixes": [], "depth": 0})
    check("list_parameters", "wheel_separation_multiplier" in lst["result"]["names"], lst["result"])
    gp = srv(ctrl + "/get_parameters", "rcl_interfaces/srv/GetParameters",
             {"names": ["wheel_separation", "wheel_separation_multiplier"]})
    ok = len(gp["values"]) == 2 and all(v["type"] == 3 for v in gp["values"])
    check("get_parameters doubles", ok, gp["values"][:1])
    sep = gp["values"][0]["double_value"] if ok else 0.3
    undeclared = srv(ctrl + "/get_parameters", "rcl_interfaces/srv/GetParameters", {"names": ["no_such"]})
    check("get_parameters of an undeclared name is empty", undeclared["values"] == [], undeclared)
    desc = srv(ctrl + "/describe_parameters", "rcl_interfaces/srv/DescribeParameters",
               {"names": ["wheel_radius"]})
    check("describe_parameters", desc["descriptors"] and desc["descriptors"][0]["type"] == 3, desc)
    sp = srv(ctrl + "/set_parameters", "rcl_interfaces/srv/SetParameters", {"parameters": [
        {"name": "wheel_separation", "value": {"type": 3, "double_value": sep}},
        {"name": "wheel_separation_multiplier", "value": {"type": 3, "double_value": -1.0}},
        {"name": "wheel_separation_multiplier", "value": {"type": 3, "double_value": 1.0}},
        {"name": "wheel_radius", "value": {"type": 2, "integer_value": 1}},
        {"name": "no_such", "value": {"type": 3, "double_value": 1.0}}]})
    r = [x["successful"] for x in sp["results"]]
    check("set_parameters: declared doubles of any value set, another type and undeclared refused",
          r == [True, True, True, False, False], sp["results"])
    check("set_parameters reasons", "not declared" in sp["results"][4]["reason"]
          and "Wrong parameter type" in sp["results"][3]["reason"], sp["results"][3:])
    try:
        srv(ctrl + "/no_such_service", "rcl_interfaces/srv/GetParameters", {})
        check("an unknown service fails", False)
    except roslibpy.core.ServiceException as e:
        check("an unknown service fails", "does not exist" in str(e), e)

    # What roslibpy cannot show: raw frames.
    n = len(frames)
    ros.send_on_ready(roslibpy.Message({"op": "call_service", "service": "/rosapi/get_time", "args": {}}))
    time.sleep(0.5)
    resp = since(n, "service_response")
    check("a call without id is answered without id", resp and "id" not in resp[0], resp[:1])
    n = len(frames)
    ros.send_on_ready(roslibpy.Message({"op": "no_such_op", "id": "x1"}))
    time.sleep(0.5)
    st = since(n, "status")
    check("an unknown op gets a status error with its id",
          st and st[0]["level"] == "error" and st[0].get("id") == "x1", st[:1])
    n = len(frames)
    ros.send_on_ready(roslibpy.Message({"op": "subscribe", "id": "bad-type", "topic": "/odom",
                                        "type": "sensor_msgs/msg/Imu"}))
    time.sleep(0.5)
    st = since(n, "status")
    check("a subscription of the wrong type is refused", st and "already established" in st[0]["msg"], st[:1])
    n = len(frames)
    ros.send_on_ready(roslibpy.Message({"op": "advertise_service", "service": "/x", "type": "std_srvs/srv/Empty"}))
    time.sleep(0.5)
    check("advertise_service is refused with a status", since(n, "status"), since(n, "status")[:1])
    # Fragments (ROSBRIDGE_PROTOCOL.md 3.1): an operation's fragment_size becomes the
    # connection's, so a subscription with fragment_size 100 gets each odometry message in
    # pieces that join into the publish operation (a large one given with the unsubscription
    # ends that); a call sent in pieces is answered.
    n = len(frames)
    ros.send_on_ready(roslibpy.Message({"op": "subscribe", "id": "frag", "topic": "/odom",
                                        "type": "nav_msgs/msg/Odometry", "fragment_size": 100}))
    time.sleep(0.6)
    ros.send_on_ready(roslibpy.Message({"op": "unsubscribe", "id": "frag", "topic": "/odom",
                                        "fragment_size": 10000000}))
    time.sleep(0.3)
    pieces = since(n, "fragment")
    first = [p for p in pieces if pieces and p["id"] == pieces[0]["id"]]
    joined = None
    if first and len(first) == first[0]["total"]:
        joined = json.loads("".join(p["data"] for p in sorted(first, key=lambda p: p["num"])))
    check("fragment_size splits a message into pieces that join",
          joined and joined.get("op") == "publish" and joined.get("topic") == "/odom"
          and all(len(p["data"]) <= 100 for p in first), (len(pieces), first[:1]))
    call = json.dumps({"op": "call_service", "id": "in-pieces", "service": "/rosapi/get_time",
                       "args": {}})
    n = len(frames)
    parts = [call[i:i + 20] for i in range(0, len(call), 20)]
    for i, part in reversed(list(enumerate(parts))):
        ros.send_on_ready(roslibpy.Message({"op": "fragment", "id": "c1", "data": part, "num": i,
                                            "total": len(parts)}))
    time.sleep(0.5)
    resp = [f for f in since(n, "service_response") if f.get("id") == "in-pieces"]
    check("a call sent in fragments is answered", resp and resp[0]["result"], resp[:1])

    ros.send_on_ready(roslibpy.Message({"op": "set_level", "level": "none"}))
    n = len(frames)
    ros.send_on_ready(roslibpy.Message({"op": "no_such_op"}))
    time.sleep(0.5)
    check("set_level none silences status", not since(n, "status"), since(n, "status")[:1])
finally:
    ros.terminate()

failed = [name for name, ok in results if not ok]
print("%d passed, %d failed" % (len(results) - len(failed), len(failed)))
sys.exit(1 if failed else 0)
