#!/usr/bin/env python3
"""Writes vectors.json: golden frames for every message of SPEC.md, and invalid inputs.

This generator is a second, independent implementation of SPEC.md (Python's struct module and
a bit-by-bit CRC), so the Rust codec is checked against the spec rather than against itself.
Run it from anywhere: `python3 protocol/vectors/generate.py`. The output is committed.
"""
import json
import math
import os
import struct

SYNC = b"\xaa\x55"
VER = 0x10
KIND = {"request": 0, "response": 1, "nack": 2, "event": 3}


def crc16(data):
    """CRC-16/IBM-3740: poly 0x1021, init 0xFFFF, no reflection, xorout 0."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


assert crc16(b"123456789") == 0x29B1


def frame(kind, seq, msg, payload, ver=VER):
    body = bytes([len(payload), ver, KIND[kind], seq, msg]) + payload
    return SYNC + body + struct.pack("<H", crc16(body))


def hexs(b):
    return " ".join("%02X" % x for x in b)


PARAMS = {  # 0.150 m / 0.149 m wheels, 0.390 m base, 2796.8 counts per wheel revolution
    "left_wheel_diameter_nm": 150_000_000,
    "right_wheel_diameter_nm": 149_000_000,
    "wheelbase_nm": 390_000_000,
    "counts_per_wheel_rev_micro": 2_796_800_000,
}


def params_bytes(p):
    return struct.pack("<IIIQ", p["left_wheel_diameter_nm"], p["right_wheel_diameter_nm"],
                       p["wheelbase_nm"], p["counts_per_wheel_rev_micro"])


vectors = []


def add(name, kind, seq, msg, payload, body):
    packet = {"seq": seq, "kind": kind}
    packet.update(body)
    vectors.append({"name": name, "hex": hexs(frame(kind, seq, msg, payload)), "packet": packet})


def req(name, seq, msg, payload, message, **fields):
    add(name, "request", seq, msg, payload, {"request": dict(message=message, **fields)})


def resp(name, seq, msg, payload, message, **fields):
    add(name, "response", seq, msg, payload, {"response": dict(message=message, **fields)})


# Requests.
req("HELLO request", 1, 0x01, bytes([1, 0]), "HELLO", host_major=1, host_min_minor=0)
req("GET_PARAMS stored", 2, 0x10, bytes([1]), "GET_PARAMS", source="stored")
req("SET_PARAMS", 3, 0x11, params_bytes(PARAMS), "SET_PARAMS", **PARAMS)
req("SAVE_PARAMS", 4, 0x12, b"", "SAVE_PARAMS")
req("RESTORE_DEFAULTS active and stored", 5, 0x13, bytes([1]), "RESTORE_DEFAULTS",
    target="active_and_stored")
req("LOAD_PARAMS", 6, 0x14, b"", "LOAD_PARAMS")
req("RESET_ODOMETRY", 7, 0x20, b"", "RESET_ODOMETRY")
req("MOVE_STRAIGHT 4 m at 0.2 m/s, queued", 8, 0x30, struct.pack("<iHB", 4_000_000, 200, 1),
    "MOVE_STRAIGHT", distance_um=4_000_000, max_speed_mm_s=200, mode="queue")
req("TURN_IN_PLACE -90 deg at 0.5 rad/s, replace", 9, 0x31,
    struct.pack("<iHB", -1_570_796, 500, 0), "TURN_IN_PLACE", angle_urad=-1_570_796,
    max_rate_mrad_s=500, mode="replace")
req("WHEEL_SPEED", 10, 0x32, struct.pack("<hhH", -100, 120, 1500), "WHEEL_SPEED",
    left_mm_s=-100, right_mm_s=120, duration_ms=1500)
req("STOP", 11, 0x33, b"", "STOP")
req("GET_STATUS", 12, 0x40, b"", "GET_STATUS")
req("READ_ENCODERS", 13, 0x41, b"", "READ_ENCODERS")
req("READ_HEADING", 14, 0x42, b"", "READ_HEADING")
req("CONFIGURE_TELEMETRY 5 ms", 15, 0x50, struct.pack("<H", 5), "CONFIGURE_TELEMETRY",
    period_ms=5)
req("CONFIGURE_WATCHDOG 500 ms", 16, 0x60, struct.pack("<H", 500), "CONFIGURE_WATCHDOG",
    timeout_ms=500)
req("HEARTBEAT", 255, 0x61, b"", "HEARTBEAT")

# Responses.
fw = b"odocal-mock".ljust(16, b"\0")
resp("HELLO response", 1, 0x01,
     bytes([1, 0]) + fw + struct.pack("<IIQHH", 0x000102, 0x3F, 0x0123456789ABCDEF, 1000, 4000),
     "HELLO", major=1, minor=0, firmware_id="odocal-mock", firmware_version=0x000102,
     capabilities=0x3F, serial_number=0x0123456789ABCDEF, max_speed_mm_s=1000,
     max_rate_mrad_s=4000)
resp("GET_PARAMS stored response", 2, 0x10,
     bytes([1]) + params_bytes(PARAMS) + struct.pack("<H", crc16(params_bytes(PARAMS))),
     "GET_PARAMS", source="stored", params=PARAMS, stored_crc=crc16(params_bytes(PARAMS)))
resp("SET_PARAMS response", 3, 0x11, params_bytes(PARAMS), "SET_PARAMS", **PARAMS)
resp("SAVE_PARAMS response", 4, 0x12, struct.pack("<H", crc16(params_bytes(PARAMS))),
     "SAVE_PARAMS", stored_crc=crc16(params_bytes(PARAMS)))
resp("RESTORE_DEFAULTS response", 5, 0x13, params_bytes(PARAMS), "RESTORE_DEFAULTS", **PARAMS)
resp("LOAD_PARAMS response", 6, 0x14, params_bytes(PARAMS), "LOAD_PARAMS", **PARAMS)
resp("RESET_ODOMETRY response", 7, 0x20, b"", "RESET_ODOMETRY")
resp("MOVE_STRAIGHT response", 8, 0x30, struct.pack("<BH", 2, 41), "MOVE_STRAIGHT",
     queue_depth=2, motion_id=41)
resp("TURN_IN_PLACE response", 9, 0x31, struct.pack("<BH", 1, 42), "TURN_IN_PLACE",
     queue_depth=1, motion_id=42)
resp("WHEEL_SPEED response", 10, 0x32, b"", "WHEEL_SPEED")
resp("STOP response", 11, 0x33, b"", "STOP")
resp("GET_STATUS response", 12, 0x40, struct.pack("<BBHIHBI", 1, 3, 42, 40, 0x0008, 1, 123456),
     "GET_STATUS", motion_state="moving", queue_depth=3, current_motion_id=42,
     completed_motions=40, fault_flags=8, watchdog_state="armed", uptime_ms=123456)
resp("READ_ENCODERS response (left counter wrapped negative)", 13, 0x41,
     struct.pack("<Iii", 4_000_000_000, -2_147_483_000, 123_456), "READ_ENCODERS",
     timestamp_us=4_000_000_000, left_counts=-2_147_483_000, right_counts=123_456)
resp("READ_HEADING response", 14, 0x42, struct.pack("<IiBB", 1000, -3_139_847, 1, 1),
     "READ_HEADING", timestamp_us=1000, heading_urad=-3_139_847, valid=True, sensor_status=1)
resp("CONFIGURE_TELEMETRY response", 15, 0x50, struct.pack("<H", 5), "CONFIGURE_TELEMETRY",
     period_ms=5)
resp("CONFIGURE_WATCHDOG response", 16, 0x60, struct.pack("<H", 500), "CONFIGURE_WATCHDOG",
     timeout_ms=500)
resp("HEARTBEAT response", 255, 0x61, b"", "HEARTBEAT")

# NACKs and events.
add("NACK out of range on field 1 of MOVE_STRAIGHT", "nack", 8, 0x30, bytes([0x03, 0x01]),
    {"msg": 0x30, "nack": {"code": "OUT_OF_RANGE", "detail": 1}})
add("NACK invalid state on SAVE_PARAMS", "nack", 4, 0x12, bytes([0x04, 0xFF]),
    {"msg": 0x12, "nack": {"code": "INVALID_STATE", "detail": 255}})
# SPEC 1.1: a VERSION_MISMATCH NACK to HELLO carries the device's own VER byte as its detail
# (here a 2.3 device); it travels, like every HELLO answer, in a frame with VER = 0x10.
add("NACK version mismatch on HELLO from a device speaking 2.3", "nack", 1, 0x01,
    bytes([0x07, 0x23]), {"msg": 0x01, "nack": {"code": "VERSION_MISMATCH", "detail": 0x23}})
add("TELEMETRY event", "event", 200, 0x51,
    struct.pack("<IIiiiBBB", 70_000, 350_000_000, 10_240, -512, 1_570_796, 1, 1, 2),
    {"event": {"message": "TELEMETRY", "sample_index": 70_000, "timestamp_us": 350_000_000,
               "left_counts": 10_240, "right_counts": -512, "heading_urad": 1_570_796,
               "heading_valid": True, "motion_state": "moving", "queue_depth": 2}})
add("MOTION_DONE event", "event", 201, 0x52, struct.pack("<HI", 42, 41),
    {"event": {"message": "MOTION_DONE", "motion_id": 42, "completed_motions": 41}})

# Streams: byte chunks as read from the link, and what the decoder must produce.
stop = frame("request", 7, 0x33, b"")
status = frame("request", 12, 0x40, b"")
bad_crc = bytearray(stop)
bad_crc[-1] ^= 0x01
streams = [
    {"name": "bad CRC", "chunks": [hexs(bad_crc)], "frames": [], "bad_crcs": 1},
    {"name": "truncated frame", "chunks": [hexs(stop[:-1])], "frames": []},
    {"name": "oversize length", "chunks": ["AA 55 F1 10 00 00 00 00 00"], "frames": [],
     "bad_headers": 1},
    {"name": "unknown major version", "chunks": [hexs(frame("request", 1, 0x33, b"", ver=0x20))],
     "frames": [], "bad_headers": 1},
    {"name": "garbage before a valid frame", "chunks": ["00 FF AA 13 AA " + hexs(stop)],
     "frames": [hexs(stop)]},
    {"name": "two frames back to back", "chunks": [hexs(stop + status)],
     "frames": [hexs(stop), hexs(status)]},
    {"name": "frame split across three reads",
     "chunks": [hexs(status[:1]), hexs(status[1:5]), hexs(status[5:])], "frames": [hexs(status)]},
    {"name": "corrupted frame then the same frame intact", "chunks": [hexs(bad_crc + stop)],
     "frames": [hexs(stop)], "bad_crcs": 1},
    {"name": "false long header before a valid frame",
     "chunks": ["AA 55 B4 10 02 0E EC " + hexs(stop)], "frames": [hexs(stop)]},
]

# Frames that are valid but whose payload a receiver must refuse (the NACK a device sends).
payload_errors = [
    {"name": "MOVE_STRAIGHT payload one byte short",
     "hex": hexs(frame("request", 1, 0x30, struct.pack("<iH", 1000, 100))),
     "nack": {"code": "BAD_LENGTH", "detail": 255}},
    {"name": "unknown request id 0x7F", "hex": hexs(frame("request", 1, 0x7F, b"")),
     "nack": {"code": "UNKNOWN_MESSAGE", "detail": 255}},
    {"name": "MOVE_STRAIGHT with undefined mode 2",
     "hex": hexs(frame("request", 1, 0x30, struct.pack("<iHB", 1000, 100, 2))),
     "nack": {"code": "OUT_OF_RANGE", "detail": 2}},
    {"name": "GET_PARAMS with undefined source 3", "hex": hexs(frame("request", 1, 0x10, b"\x03")),
     "nack": {"code": "OUT_OF_RANGE", "detail": 0}},
]

# Device rules (SPEC.md §7, 1.1): request sequences sent to a freshly powered-up device, with the
# answer each must get. A device implementation checks itself by replaying them (odocal's mock
# does, in tests/spec_rules.rs). A step is one of:
#   [request, answer]                   send; then device time runs until the base is idle
#                                       (virtual time: queued motions complete)
#   {"send": request, "answer": a}      send; no device time passes (motions keep running)
#   {"advance_ms": n}                   n ms of device time pass with the host silent
#   {"repeat": n, "send_cycle": [r...], "answer": a}
#                                       n requests, taken from the cycle in turn, each as
#                                       [request, answer]
# An answer may hold "fields": response fields that must have these values (names and enum
# spellings as in the frame vectors' "packet"). A step may hold "motion_done": the MOTION_DONE
# events, as [motion_id, completed_motions], that the device emits during the step (its answer
# and the time that passes), exactly and in order; "telemetry_min" the fewest TELEMETRY events
# it emits in that time.
def req(seq, msg, payload=b""):
    return hexs(frame("request", seq, msg, payload))


def ok(msg, **fields):
    answer = {"kind": "response", "msg": msg}
    if fields:
        answer["fields"] = fields
    return answer


def refused(msg, code, detail):
    return {"kind": "nack", "msg": msg, "code": code, "detail": detail}


def hold(request, answer, **extra):
    step = {"send": request, "answer": answer}
    step.update(extra)
    return step


def wait(ms, **extra):
    step = {"advance_ms": ms}
    step.update(extra)
    return step


def move(seq, distance_um, mode, speed_mm_s=100):
    return req(seq, 0x30, struct.pack("<iHB", distance_um, speed_mm_s, mode))


def turn(seq, angle_urad, mode=1, rate_mrad_s=500):
    return req(seq, 0x31, struct.pack("<iHB", angle_urad, rate_mrad_s, mode))


def round_half_away(x):
    return int(math.floor(abs(x) + 0.5)) * (1 if x >= 0 else -1)


def counts(arc_m, diameter_nm):
    """A wheel's target in counts for `arc_m` of travel with PARAMS (SPEC.md §5 MOVE_STRAIGHT),
    rounded as §7.6 says."""
    cpr = PARAMS["counts_per_wheel_rev_micro"] / 1e6
    return round_half_away(arc_m / (math.pi * diameter_nm / 1e9) * cpr)


QUEUE, REPLACE = 1, 0
TEN_M = 10_000_000  # 100 s at 0.1 m/s: still running whenever the rules look
STATUS = 0x40
FOUR_PI_URAD = 12_566_370  # floor(4π · 10^6): the largest angle a turn may ask for
# 0.114695 m: 680.714 counts on the 0.150 m left wheel, 685.283 on the 0.149 m right one, so
# two moves end 2·681 and 2·685 counts on (unrounded targets would drift to 1361 and 1371).
ROUNDING_UM = 114_695
ROUNDING_URAD = 588_179  # a turn whose wheel targets fall likewise
left_move = counts(ROUNDING_UM / 1e6, PARAMS["left_wheel_diameter_nm"])
right_move = counts(ROUNDING_UM / 1e6, PARAMS["right_wheel_diameter_nm"])
turn_arc = ROUNDING_URAD / 1e6 * PARAMS["wheelbase_nm"] / 1e9 / 2
left_turn = counts(-turn_arc, PARAMS["left_wheel_diameter_nm"])
right_turn = counts(turn_arc, PARAMS["right_wheel_diameter_nm"])
assert (left_move, right_move, left_turn, right_turn) == (681, 685, -681, 685)
idle = dict(motion_state="idle", queue_depth=0, current_motion_id=0)

device_rules = [
    {"name": "7.1 a host of another major gets VERSION_MISMATCH with the device's version",
     "steps": [[req(1, 0x01, bytes([2, 0])), refused(0x01, "VERSION_MISMATCH", 0x11)]]},
    {"name": "7.2 a retried request gets the remembered NACK again",
     "steps": [[req(2, 0x30, struct.pack("<iHB", 1000, 0, 0)), refused(0x30, "OUT_OF_RANGE", 1)],
               [req(2, 0x30, struct.pack("<iHB", 1000, 0, 0)), refused(0x30, "OUT_OF_RANGE", 1)]]},
    {"name": "7.3 queue_depth counts the running motion, ids count from 1, at least 4 are queued",
     "steps": [hold(move(1, TEN_M, QUEUE), ok(0x30, queue_depth=1, motion_id=1)),
               hold(move(2, TEN_M, QUEUE), ok(0x30, queue_depth=2, motion_id=2)),
               hold(move(3, TEN_M, QUEUE), ok(0x30, queue_depth=3, motion_id=3)),
               hold(move(4, TEN_M, QUEUE), ok(0x30, queue_depth=4, motion_id=4)),
               hold(req(5, STATUS), ok(STATUS, motion_state="moving", queue_depth=4,
                                       current_motion_id=1, completed_motions=0)),
               hold(req(6, 0x33), ok(0x33), motion_done=[]),
               wait(2000, motion_done=[]),
               hold(req(7, STATUS), ok(STATUS, completed_motions=0, **idle))]},
    {"name": "7.3 motion_id wraps from 65535 to 1, never to the reserved 0",
     "steps": [{"repeat": 65534, "send_cycle": [move(1, 1000, QUEUE, 1000),
                                                move(2, 1000, QUEUE, 1000)],
                "answer": ok(0x30)},
               [move(3, 1000, QUEUE, 1000), ok(0x30, queue_depth=1, motion_id=65535)],
               [move(4, 1000, QUEUE, 1000), ok(0x30, queue_depth=1, motion_id=1)],
               [req(5, STATUS), ok(STATUS, completed_motions=65536, **idle)]]},
    {"name": "7.4 only a motion that reaches its targets completes: a replaced or stopped one "
             "counts nothing and emits nothing",
     "steps": [hold(move(1, TEN_M, QUEUE), ok(0x30, queue_depth=1, motion_id=1)),
               wait(1000, motion_done=[]),
               hold(move(2, 100_000, REPLACE), ok(0x30, queue_depth=1, motion_id=2)),
               wait(5000, motion_done=[[2, 1]]),
               hold(req(3, STATUS), ok(STATUS, completed_motions=1, **idle)),
               hold(move(4, TEN_M, QUEUE), ok(0x30, queue_depth=1, motion_id=3)),
               wait(500),
               hold(req(5, 0x33), ok(0x33), motion_done=[]),
               wait(2000, motion_done=[]),
               hold(req(6, STATUS), ok(STATUS, completed_motions=1, **idle))]},
    {"name": "7.4 WHEEL_SPEED is a motion: it replaces the queue, takes the next id and completes "
             "when its duration runs out; with duration 0 it never completes",
     "steps": [hold(move(1, TEN_M, QUEUE), ok(0x30, motion_id=1)),
               hold(move(2, TEN_M, QUEUE), ok(0x30, motion_id=2)),
               hold(req(3, 0x32, struct.pack("<hhH", 100, 100, 1000)), ok(0x32)),
               hold(req(4, STATUS), ok(STATUS, motion_state="moving", queue_depth=1,
                                       current_motion_id=3, completed_motions=0)),
               wait(3000, motion_done=[[3, 1]]),
               hold(req(5, STATUS), ok(STATUS, completed_motions=1, **idle)),
               hold(req(6, 0x32, struct.pack("<hhH", 100, -100, 0)), ok(0x32)),
               wait(5000, motion_done=[]),
               hold(req(7, STATUS), ok(STATUS, motion_state="moving", current_motion_id=4,
                                       completed_motions=1)),
               hold(req(8, 0x33), ok(0x33)),
               wait(2000, motion_done=[]),
               hold(req(9, STATUS), ok(STATUS, completed_motions=1, **idle))]},
    {"name": "7.5 fields are checked in payload order: the first offending field is named",
     "steps": [[req(3, 0x30, struct.pack("<iHB", 0, 0, 0)), refused(0x30, "OUT_OF_RANGE", 0)]]},
    {"name": "7.6 a turn of exactly floor(4π·10^6) µrad is accepted, one more is refused",
     "steps": [[req(4, 0x31, struct.pack("<iHB", FOUR_PI_URAD, 1000, 0)), ok(0x31)],
               [req(5, 0x31, struct.pack("<iHB", FOUR_PI_URAD + 1, 1000, 0)),
                refused(0x31, "OUT_OF_RANGE", 0)],
               [req(6, 0x31, struct.pack("<iHB", -FOUR_PI_URAD - 1, 1000, 0)),
                refused(0x31, "OUT_OF_RANGE", 0)]]},
    {"name": "7.6 wheel targets are rounded to whole counts, halves away from zero, and wheels "
             "stop on them: two moves end twice one move's rounded target",
     "steps": [[req(1, 0x11, params_bytes(PARAMS)), ok(0x11)],
               [req(2, 0x20), ok(0x20)],
               [move(3, ROUNDING_UM, QUEUE), ok(0x30)],
               [move(4, ROUNDING_UM, QUEUE), ok(0x30)],
               [req(5, 0x41), ok(0x41, left_counts=2 * left_move, right_counts=2 * right_move)],
               [req(6, 0x20), ok(0x20)],
               [move(7, -ROUNDING_UM, QUEUE), ok(0x30)],
               [move(8, -ROUNDING_UM, QUEUE), ok(0x30)],
               [req(9, 0x41), ok(0x41, left_counts=-2 * left_move, right_counts=-2 * right_move)],
               [req(10, 0x20), ok(0x20)],
               [turn(11, ROUNDING_URAD), ok(0x31)],
               [turn(12, ROUNDING_URAD), ok(0x31)],
               [req(13, 0x41), ok(0x41, left_counts=2 * left_turn, right_counts=2 * right_turn)]]},
    {"name": "7.7 a watchdog trip stops the base: idle, fault bit 3, watchdog tripped; motions "
             "are refused until HEARTBEAT acknowledges it, and the stopped motion does not resume",
     "steps": [hold(req(1, 0x60, struct.pack("<H", 100)), ok(0x60, timeout_ms=100)),
               hold(move(2, TEN_M, QUEUE), ok(0x30, motion_id=1)),
               wait(3000, motion_done=[]),
               hold(req(3, STATUS), ok(STATUS, completed_motions=0, fault_flags=8,
                                       watchdog_state="tripped", **idle)),
               hold(turn(4, 1_000_000), refused(0x31, "INVALID_STATE", 0xFF)),
               hold(move(5, 0, QUEUE), refused(0x30, "OUT_OF_RANGE", 0)),
               hold(req(6, 0x61), ok(0x61)),
               hold(req(7, STATUS), ok(STATUS, completed_motions=0, fault_flags=0,
                                       watchdog_state="armed", **idle)),
               hold(req(8, 0x61), ok(0x61), motion_done=[]),
               hold(req(9, STATUS), ok(STATUS, completed_motions=0, **idle))]},
    {"name": "7.7 CONFIGURE_WATCHDOG acknowledges a trip too, and 0 leaves the watchdog disabled",
     "steps": [hold(req(1, 0x60, struct.pack("<H", 100)), ok(0x60)),
               hold(move(2, TEN_M, QUEUE), ok(0x30)),
               wait(3000),
               hold(req(3, STATUS), ok(STATUS, fault_flags=8, watchdog_state="tripped")),
               hold(req(4, 0x60, struct.pack("<H", 0)), ok(0x60, timeout_ms=0)),
               hold(req(5, STATUS), ok(STATUS, fault_flags=0, watchdog_state="disabled",
                                       **idle)),
               [move(6, 1000, QUEUE), ok(0x30, motion_id=2), ],
               [req(7, STATUS), ok(STATUS, completed_motions=1, **idle)]]},
    {"name": "7.8 telemetry and watchdog settings out of range are refused, not clamped",
     "steps": [[req(7, 0x50, struct.pack("<H", 4)), refused(0x50, "OUT_OF_RANGE", 0)],
               [req(8, 0x50, struct.pack("<H", 1001)), refused(0x50, "OUT_OF_RANGE", 0)],
               [req(9, 0x50, struct.pack("<H", 5)), ok(0x50)],
               [req(10, 0x60, struct.pack("<H", 49)), refused(0x60, "OUT_OF_RANGE", 0)],
               [req(11, 0x60, struct.pack("<H", 10_001)), refused(0x60, "OUT_OF_RANGE", 0)],
               [req(12, 0x60, struct.pack("<H", 0)), ok(0x60)]]},
    {"name": "7.9 with nothing ever saved, GET_PARAMS stored is STORAGE_FAILURE and LOAD loads "
             "the factory defaults",
     "steps": [[req(13, 0x10, b"\x01"), refused(0x10, "STORAGE_FAILURE", 0)],
               [req(14, 0x14), ok(0x14)]]},
    {"name": "7.10 while moving, parameter changes and RESET_ODOMETRY are refused INVALID_STATE "
             "(after the field checks); everything else is accepted",
     "steps": [hold(move(1, TEN_M, QUEUE), ok(0x30, motion_id=1)),
               hold(req(2, 0x11, params_bytes(PARAMS)), refused(0x11, "INVALID_STATE", 0xFF)),
               hold(req(3, 0x12), refused(0x12, "INVALID_STATE", 0xFF)),
               hold(req(4, 0x13, bytes([0])), refused(0x13, "INVALID_STATE", 0xFF)),
               hold(req(5, 0x14), refused(0x14, "INVALID_STATE", 0xFF)),
               hold(req(6, 0x20), refused(0x20, "INVALID_STATE", 0xFF)),
               hold(req(7, 0x11, params_bytes(dict(PARAMS, left_wheel_diameter_nm=1))),
                    refused(0x11, "OUT_OF_RANGE", 0)),
               hold(req(8, 0x10, bytes([0])), ok(0x10)),
               hold(req(9, 0x41), ok(0x41)),
               hold(req(10, 0x42), ok(0x42)),
               hold(req(11, 0x50, struct.pack("<H", 0)), ok(0x50)),
               hold(req(12, 0x60, struct.pack("<H", 0)), ok(0x60)),
               hold(req(13, 0x61), ok(0x61)),
               hold(req(14, 0x01, bytes([1, 0])), ok(0x01)),
               hold(move(15, TEN_M, QUEUE), ok(0x30, queue_depth=2, motion_id=2)),
               hold(req(16, STATUS), ok(STATUS, motion_state="moving", queue_depth=2)),
               hold(req(17, 0x33), ok(0x33)),
               wait(2000),
               hold(req(18, 0x11, params_bytes(PARAMS)), ok(0x11))]},
    {"name": "7.11 HELLO is not remembered: a repeated HELLO is answered afresh",
     "steps": [[req(15, 0x01, bytes([1, 0])), ok(0x01)], [req(15, 0x01, bytes([1, 0])), ok(0x01)]]},
    {"name": "7.11 HELLO changes no state: parameters, watchdog and telemetry carry on",
     "steps": [hold(req(1, 0x11, params_bytes(PARAMS)), ok(0x11)),
               hold(req(2, 0x60, struct.pack("<H", 1000)), ok(0x60)),
               hold(req(3, 0x50, struct.pack("<H", 100)), ok(0x50)),
               hold(req(4, 0x01, bytes([1, 0])), ok(0x01)),
               hold(req(5, 0x10, bytes([0])), ok(0x10, source="active", params=PARAMS)),
               hold(req(6, STATUS), ok(STATUS, watchdog_state="armed")),
               wait(1000, telemetry_min=9)]},
]

out = {
    "spec": "odocal serial protocol 1.1",
    "crc": {"name": "CRC-16/IBM-3740", "poly": "0x1021", "init": "0xFFFF", "refin": False,
            "refout": False, "xorout": "0x0000", "check": "0x29B1"},
    "frames": vectors,
    "streams": streams,
    "payload_errors": payload_errors,
    "device_rules": device_rules,
}
path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "vectors.json")
with open(path, "w") as f:
    json.dump(out, f, indent=1)
    f.write("\n")
print("wrote", path, len(vectors), "frames,", len(streams), "streams")
