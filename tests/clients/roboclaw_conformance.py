"""Basicmicro's own Python library (basicmicro, pinned in .ci/requirements.txt) against a RoboClaw
in packet serial mode: what odocal's mock must do for the vendor's client, checked with a
library odocal did not write, against the layouts of the RoboClaw user manual.

usage: python roboclaw_conformance.py roboclaw:/dev/pts/N TIME_SCALE

TIME_SCALE is the device's robot seconds per wall-clock second (1 for hardware): it bounds how
far a motor can have moved between two commands. Prints one line per check (PASS/FAIL name --
detail) and exits non-zero on any failure. The device must be at rest with nothing buffered.
"""
import binascii
import struct
import sys
import time

from basicmicro import Basicmicro

path = sys.argv[1].split(":", 1)[1] if sys.argv[1].startswith("roboclaw:") else sys.argv[1]
scale = float(sys.argv[2])
A = 0x80
IDLE = 0x80
results = []


def check(name, ok, detail=""):
    results.append((name, bool(ok)))
    print(("PASS " if ok else "FAIL ") + name + (" -- " + str(detail) if detail else ""), flush=True)


def crc(b):
    # CRC-16/XMODEM, computed independently of basicmicro.
    return binascii.crc_hqx(bytes(b), 0)


def frame(address, command, data=b""):
    head = bytes([address, command]) + bytes(data)
    return head + struct.pack(">H", crc(head))


def s32(v):
    return v - (1 << 32) if v & 0x80000000 else v


dev = Basicmicro(path, 38400, timeout=0.01, retries=2)
if not dev.Open():
    check("open " + path, False)
    sys.exit(1)
port = dev._port

# Every write() the library makes, to compare its bytes with the manual's layouts.
calls = []
_write = port.write


def _tap(b):
    calls.append(bytes(b))
    return _write(b)


port.write = _tap


def sent(fn, *args):
    """Calls fn; returns its result, the bytes it sent and in how many write() calls."""
    calls.clear()
    r = fn(*args)
    return r, b"".join(calls), len(calls)


def silent(raw, wait=0.1):
    """Writes raw bytes; True when nothing comes back within `wait`, then lets the line go
    quiet (the device drops a partial packet after 10 ms)."""
    port.reset_input_buffer()
    _write(raw)
    deadline = time.monotonic() + wait
    got = b""
    while time.monotonic() < deadline:
        got += port.read(port.in_waiting or 1) if port.in_waiting else b""
        time.sleep(0.005)
    time.sleep(0.03)
    return got == b"", got


def section(name, fn):
    try:
        fn()
    except Exception as e:  # a raised PacketTimeoutError is a failed check, not a crash
        check(name + " (raised)", False, repr(e))


def encoders():
    r = dev.GetEncoders(A)
    return s32(r[1]), s32(r[2])


def buffers():
    r = dev.ReadBuffers(A)
    return r[1], r[2]


def wait_idle(limit=20.0):
    """Polls 47 until both buffers are idle; returns the distinct states seen, in order."""
    seen = []
    end = time.monotonic() + limit
    while time.monotonic() < end:
        b = buffers()
        if not seen or seen[-1] != b:
            seen.append(b)
        if b == (IDLE, IDLE):
            break
        time.sleep(0.005)
    return seen


def leg46(accel, s1, d1, s2, d2, flag):
    return struct.pack(">IiIiIB", accel, s1, d1, s2, d2, flag)


def identity():
    r, wire, _ = sent(dev.ReadVersion, A)
    check("21 ReadVersion", r[0] and "Roboclaw" in r[1] and r[1].endswith("\n"), r)
    check("21 request is [address, 21]", wire == bytes([A, 21]), wire.hex(" "))
    r, wire, _ = sent(dev.ReadMainBatteryVoltage, A)
    check("24 ReadMainBatteryVoltage (tenths of a volt)", r[0] and 60 <= r[1] <= 340, r)
    check("24 request is [address, 24]", wire == bytes([A, 24]), wire.hex(" "))
    r = dev.ReadLogicBatteryVoltage(A)
    check("25 ReadLogicBatteryVoltage", r[0] and 50 <= r[1] <= 340, r)
    r, wire, _ = sent(dev.ReadError, A)
    check("90 ReadError: 4-byte status, 0 when healthy", tuple(r) == (1, 0), r)
    check("90 request is [address, 90]", wire == bytes([A, 90]), wire.hex(" "))
    r = dev.ReadTemp(A)
    check("82 ReadTemp (tenths of a degree)", r[0] and 0 < r[1] < 1000, r)
    r = dev.ReadTemp2(A)
    check("83 ReadTemp2", r[0] and 0 < r[1] < 1000, r)
    r = dev.ReadEncoderModes(A)
    check("91 ReadEncoderModes", tuple(r) == (1, 0, 0), r)
    r = dev.GetConfig(A)
    check("99 GetConfig: packet serial mode", r[0] and r[1] & 0x0003 == 0x0003, r)
    ok, wire, _ = sent(dev.SetConfig, A, r[1])
    check("98 SetConfig acknowledged, read back", ok and dev.GetConfig(A) == r, wire.hex(" "))
    r = dev.ReadM1VelocityPID(A)
    check("55 ReadM1VelocityPID: the manual's defaults", tuple(r) == (True, 1.0, 0.5, 0.25, 44000), r)
    r = dev.ReadM2VelocityPID(A)
    check("56 ReadM2VelocityPID", tuple(r) == (True, 1.0, 0.5, 0.25, 44000), r)
    # Over USB a RoboClaw answers any address 0x80-0x87, its CRC over the address sent.
    answered = [a for a in range(0x80, 0x88) if dev.ReadMainBatteryVoltage(a)[0]]
    check("any address 0x80-0x87 answered, CRC over it", answered == list(range(0x80, 0x88)),
          [hex(a) for a in answered])


def serial_timeout():
    ok, wire, _ = sent(dev.SetTimeout, A, 0.5)
    check("14 SetTimeout(0.5 s) acknowledged", ok)
    check("14 frame per the manual", wire == frame(A, 14, b"\x05"), wire.hex(" "))
    r, wire, _ = sent(dev.GetTimeout, A)
    check("15 GetTimeout round trip", tuple(r) == (True, 0.5), r)
    check("15 request is [address, 15]", wire == bytes([A, 15]), wire.hex(" "))
    check("14 SetTimeout(0) turns it off", dev.SetTimeout(A, 0) and dev.GetTimeout(A) == (True, 0.0))


def bad_packets():
    spoilt = bytearray(frame(A, 14, b"\x07"))
    spoilt[-1] ^= 0x01
    quiet, got = silent(bytes(spoilt))
    check("a bad CRC gets no answer", quiet, got.hex(" "))
    check("a bad CRC changes nothing", dev.GetTimeout(A) == (True, 0.0), dev.GetTimeout(A))
    quiet, got = silent(bytes([A, 200]))
    check("an unknown command gets no answer", quiet, got.hex(" "))
    # The manual's old 94 without the key: not a complete packet for current firmware.
    quiet, got = silent(frame(A, 94))
    check("94 without its key gets no answer", quiet, got.hex(" "))
    check("the line works after them", dev.ReadMainBatteryVoltage(A)[0])


def queued_and_replacing_legs():
    ok, wire, _ = sent(dev.ResetEncoders, A)
    check("20 ResetEncoders", ok and encoders() == (0, 0), wire.hex(" "))
    check("20 frame per the manual", wire == frame(A, 20), wire.hex(" "))
    check("47 idle: 0x80 each", buffers() == (IDLE, IDLE), buffers())
    # Forward 3000 then back 3000 on M1, back 3000 twice on M2, both queued (flag 0).
    ok, wire, pieces = sent(dev.SpeedAccelDistanceM1M2, A, 3000, 3000, 3000, -3000, 3000, 0)
    check("46 queued on idle motors acknowledged", ok)
    check("46 frame per the manual", wire == frame(A, 46, leg46(3000, 3000, 3000, -3000, 3000, 0)),
          wire.hex(" "))
    check("46 written in pieces (field by field)", pieces > 2, pieces)
    check("47 while the first runs, none waiting: 0", buffers() == (0, 0), buffers())
    check("46 second, queued", dev.SpeedAccelDistanceM1M2(A, 3000, -3000, 3000, -3000, 3000, 0))
    check("47 one waiting: 1", buffers() == (1, 1), buffers())
    seen = wait_idle()
    check("47 then counts down to executing (0), then idle (0x80)",
          seen == [(1, 1), (0, 0), (IDLE, IDLE)], seen)
    e = encoders()
    check("queued 46 then 46: the distances sum", e == (0, -6000), e)
    r1, r2 = dev.ReadEncM1(A), dev.ReadEncM2(A)
    check("16 ReadEncM1 agrees, forward status", (r1[0], s32(r1[1]), r1[2] & 0x02) == (1, 0, 0), r1)
    check("17 ReadEncM2 agrees; counted below zero: underflow bit",
          (r2[0], s32(r2[1]), r2[2] & 0x01) == (1, -6000, 1), r2)
    r2 = dev.ReadEncM2(A)
    check("17 the underflow bit clears once read", r2[2] & 0x01 == 0, r2)

    # An immediate 46 (flag 1) stops the running leg and deletes the queue.
    dev.ResetEncoders(A)
    t0 = time.monotonic()
    dev.SpeedAccelDistanceM1M2(A, 1000, 3000, 3000, -3000, 3000, 0)
    dev.SpeedAccelDistanceM1M2(A, 1000, 3000, 3000, -3000, 3000, 0)
    queued = buffers()
    ok = dev.SpeedAccelDistanceM1M2(A, 1000, -3000, 3000, 3000, 3000, 1)
    dt = time.monotonic() - t0
    check("46 immediate (flag 1) acknowledged", ok and queued == (1, 1), queued)
    check("47 after it: the queue deleted, it runs", buffers() == (0, 0), buffers())
    wait_idle()
    e = encoders()
    # How far the first leg can have gone from rest at 1000 counts/s² before it was replaced.
    reach = 0.5 * 1000 * (scale * dt) ** 2 + 1
    check("immediate 46 replaced the running leg and the queue",
          -3000 <= e[0] <= -3000 + reach and 3000 - reach <= e[1] <= 3000, (e, round(reach, 1)))


def single_and_other_buffered():
    dev.ResetEncoders(A)
    # Slow enough that the first legs still run when the last command is queued.
    check("41 SpeedDistanceM1", dev.SpeedDistanceM1(A, 1000, 1000, 1))
    check("42 SpeedDistanceM2 queued", dev.SpeedDistanceM2(A, -1000, 500, 0))
    check("43 SpeedDistanceM1M2 queued", dev.SpeedDistanceM1M2(A, 4000, 500, -4000, 500, 0))
    check("44 SpeedAccelDistanceM1 queued", dev.SpeedAccelDistanceM1(A, 20000, 4000, 500, 0))
    check("45 SpeedAccelDistanceM2 queued", dev.SpeedAccelDistanceM2(A, 20000, -4000, 500, 0))
    check("51 SpeedAccelDistanceM1M2_2 queued",
          dev.SpeedAccelDistanceM1M2_2(A, 20000, 4000, 500, 30000, -4000, 500, 0))
    check("47 per motor", buffers() == (3, 3), buffers())
    wait_idle()
    e = encoders()
    check("41-45, 51 travel their distances per motor", e == (2500, -2000), e)


def speeds():
    dev.ResetEncoders(A)
    ok, wire, _ = sent(dev.SpeedM1M2, A, 1500, -1500)
    check("37 SpeedM1M2 acknowledged", ok)
    check("37 frame per the manual", wire == frame(A, 37, struct.pack(">ii", 1500, -1500)), wire.hex(" "))
    time.sleep(0.2)
    a = encoders()
    time.sleep(0.2)
    b = encoders()
    check("37 drives the encoders at the signed speeds", 0 < a[0] < b[0] and 0 > a[1] > b[1], (a, b))
    check("47 under a speed command: 0x80 (not buffered)", buffers() == (IDLE, IDLE), buffers())
    r = dev.ReadSpeedM1(A)
    check("18 ReadSpeedM1: counts/s, status 0 forward", tuple(r) == (1, 1500, 0), r)
    r = dev.ReadSpeedM2(A)
    check("19 ReadSpeedM2: signed, status 1 backwards", (r[0], s32(r[1]), r[2]) == (1, -1500, 1), r)
    r = dev.ReadISpeedM1(A)
    check("30 ReadISpeedM1", tuple(r) == (1, 1500, 0), r)
    r = dev.ReadISpeedM2(A)
    check("31 ReadISpeedM2", (r[0], s32(r[1]), r[2]) == (1, -1500, 1), r)
    r = dev.GetISpeeds(A)
    check("79 GetISpeeds", (r[0], s32(r[1]), s32(r[2])) == (1, 1500, -1500), r)
    r = dev.GetSpeeds(A)
    check("108 GetSpeeds", (r[0], s32(r[1]), s32(r[2])) == (1, 1500, -1500), r)
    r = dev.ReadPWMs(A)
    check("48 ReadPWMs: signed duties", r[0] and r[1] > 0 > r[2], r)
    r = dev.ReadCurrents(A)
    check("49 ReadCurrents", r[0] and r[1] > 0 and r[2] > 0, r)
    check("50 SpeedAccelM1M2_2", dev.SpeedAccelM1M2_2(A, 10 ** 7, -800, 10 ** 7, 900))
    time.sleep(0.05)
    r1, r2 = dev.ReadSpeedM1(A), dev.ReadSpeedM2(A)
    check("50 sets each motor's speed", (s32(r1[1]), r2[1]) == (-800, 900), (r1, r2))
    check("35 SpeedM1", dev.SpeedM1(A, 700))
    check("38 SpeedAccelM1", dev.SpeedAccelM1(A, 10 ** 7, 600))
    check("40 SpeedAccelM1M2", dev.SpeedAccelM1M2(A, 10 ** 7, 300, -300))
    time.sleep(0.05)
    r = dev.GetISpeeds(A)
    check("35-40 take effect", (s32(r[1]), s32(r[2])) == (300, -300), r)
    check("34 DutyM1M2", dev.DutyM1M2(A, 16384, -16384))
    time.sleep(0.05)
    r = dev.ReadPWMs(A)
    check("48 reads the duties set", tuple(r) == (True, 16384, -16384), r)
    ok, wire, _ = sent(dev.SpeedM1M2, A, 0, 0)
    check("37 SpeedM1M2(0, 0) stops", ok and wire == frame(A, 37, bytes(8)), wire.hex(" "))
    time.sleep(0.05)
    a = encoders()
    time.sleep(0.1)
    check("stopped: encoders stand", encoders() == a and dev.ReadSpeedM1(A)[1] == 0, (a, encoders()))


def serial_timeout_stops():
    check("14 SetTimeout(0.3 s)", dev.SetTimeout(A, 0.3))
    before = encoders()
    check("37 drive", dev.SpeedM1M2(A, 1000, 1000))
    time.sleep(0.6)  # silence: no packet for twice the timeout
    a = encoders()
    time.sleep(0.1)
    b = encoders()
    check("the serial timeout stopped both motors after they moved",
          a == b and a[0] > before[0] and a[1] > before[1], (before, a, b))
    check("14 SetTimeout(0)", dev.SetTimeout(A, 0))


def nvm_and_pid():
    ok, wire, _ = sent(dev.SetM1VelocityPID, A, 2.0, 0.5, 0.25, 30000)
    check("28 SetM1VelocityPID (sent D, P, I, QPPS)", ok and wire == frame(
        A, 28, struct.pack(">IIII", 16384, 131072, 32768, 30000)), wire.hex(" "))
    r = dev.ReadM1VelocityPID(A)
    check("55 reads it back as P, I, D, QPPS", tuple(r) == (True, 2.0, 0.5, 0.25, 30000), r)
    dev.SetM1VelocityPID(A, 1.0, 0.5, 0.25, 44000)
    ok, wire, _ = sent(dev.WriteNVM, A)
    check("94 WriteNVM with the key E2 2E AB 7A acknowledged", ok)
    check("94 frame with the key", wire == frame(A, 94, bytes.fromhex("E22EAB7A")), wire.hex(" "))


section("identity and reads", identity)
section("serial timeout 14/15", serial_timeout)
section("bad packets", bad_packets)
section("buffered 46", queued_and_replacing_legs)
section("buffered 41-45, 51", single_and_other_buffered)
section("speed commands", speeds)
section("serial timeout stops", serial_timeout_stops)
section("PID and NVM", nvm_and_pid)
dev.close()
print("%d passed, %d failed" % (sum(ok for _, ok in results), sum(not ok for _, ok in results)))
sys.exit(0 if results and all(ok for _, ok in results) else 1)
