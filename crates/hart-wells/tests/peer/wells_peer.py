#!/usr/bin/env python3
"""wells_peer.py - an independent test peer for the well-monitoring network.

Written from docs/wells.md only (no source of the Rust implementation was read),
Python 3.9+ standard library only. It opens a serial device (a real port or one end
of a socat pseudo-terminal pair), sets it raw (1200 bit/s, 8 data bits, odd parity,
1 stop bit where the device accepts it; failures are ignored, as on a pty) and plays
ONE role of the network, chosen by a subcommand:

  poll-sensor PATH --address N [--command 1|14] [--count K] [--timeout S] [--retries R]
      a concentrator polling one sensor (command 1 or 14), K requests 0.2 s apart.
  sensors PATH [--temperature-addr 1] [--level-addr 2] [--status normal|abnormal]
          [--diag 0..3] [--silent ADDR]... [--base-minute M] [--run-for S]
      the two sensors of one well's bus (runs until killed, or for S seconds).
  pull PATH --well W [--address A] [--ack M] [--stop-after B] [--timeout S]
      the PC (or the handheld) fetching stored minutes with command 144.
  concentrator PATH --well W [--address A] --minutes START COUNT
               [--invalid MINUTE]... [--run-for S]
      a concentrator serving COUNT stored minutes with command 144 (also 14, 160).
  raw PATH HEX [--timeout S]
      (extra) sends HEX bytes as they are, logs every frame heard for S seconds.

Frames (HART short frames, docs/wells.md "The line"):
  FF FF | delimiter (02 request, 06 reply) | address | command | byte count |
  [2 status bytes, replies only] | data | check = XOR of delimiter .. last data byte.
  The receiver accepts 2 or more FF before a delimiter and skips any other byte
  (logged as "garbage"); a frame whose check byte is wrong is logged as "bad_frame"
  and never answered; the search then resumes one byte after its delimiter. A frame
  left incomplete for 0.5 s is dropped the same way. On a real port a character
  with a parity error is discarded by the driver (IGNPAR|INPCK), so its frame fails
  the length/check test and is not answered either.

Output: one JSON object per line on stdout, each with "event" and "time" (Unix
seconds). Bytes are upper-case hex separated by spaces ("FF FF 02 01 01 00 02").
The last line is always {"event": "summary", "role": ..., "ok": bool, ...}.
NaN floats are written as null (stdout is strict JSON). Exit codes: 0 success,
1 protocol failure (message on stderr, also "error" in the summary), 2 timeout
(no valid reply in time, after the retries), 3 usage or setup error (bad options,
device cannot be opened).

Common events:
  {"event":"port","path":P,"raw":true,"baud":1200|null,"parity":"odd"|"unchanged"}
  {"event":"tx","hex":H,"delimiter":"request"|"reply","address":A,"command":C,
   "byte_count":BC,"status":[S1,S2]|null,"data":H}
  {"event":"rx", same fields as tx}
  {"event":"bad_frame","hex":H,"reason":R}
  {"event":"garbage","hex":H}
  {"event":"ignored","reason":R,"address":A,"command":C}

WHAT `sensors` SENDS (deterministic, so a test can predict it):
  Let t = --base-minute M if given (a frozen clock: every answer uses the same t),
  otherwise t = floor(time.time() / 60) at the moment the request is answered.
  Group i (i = 0, 1, 2, oldest first) is the minute  m_i = t - 3 + i  (group 2 is the
  minute that ended last), and
    temperature sensor (--temperature-addr, default 1), command 1 reply:
      status 00 00, byte count 0B, group i = 24-bit big-endian (8000000 + m_i % 1000)
    level sensor (--level-addr, default 2), command 1 reply:
      status 00 00, byte count 14, group i = level counts (4000000 + m_i % 1000)
      then the sensor's own temperature counts 3000000, each 24-bit big-endian.
    --status abnormal: status FF FF and every group FF FF FF (byte counts unchanged).
    command 14: status 0E DD (DD = --diag, default 00), byte count 02, no data.
      (--diag does not change the command 1 answer; use --status for that.)
    any other command: status 40 00 (response code 64), byte count 02, no data.
    requests for another address, for a --silent address, reply frames and frames
    with a bad check byte: not answered (logged as "ignored" / "bad_frame").
  Every answer is logged (summary on SIGTERM/SIGINT or after --run-for:
  {"event":"summary","role":"sensors","ok":true,"answered":N,"ignored":N,
   "bad_frames":N[,"stopped_by_signal":true]}):
  {"event":"answered","address":A,"command":C,"kind":"temperature"|"level",
   "status":[S1,S2],"minutes":[m0,m1,m2]|null,"groups":[...]|null}
  groups: temperature [c0,c1,c2], level [[l0,ls0],[l1,ls1],[l2,ls2]].

`poll-sensor` events (exit 1 on a reply with another address or command, a byte
  count other than 0B/14 for command 1 or 02 for command 14, a command 1 status other
  than 00 00 / FF FF, a response code, a command 14 status byte 1 other than 0E or a
  diagnosis above 03; exit 2 when no reply comes within --timeout after --retries):
  {"event":"reading","index":k,"address":A,"command":1,"kind":"temperature"|"level",
   "status":[S1,S2],"abnormal":bool,"groups":[c0,c1,c2] | [[l0,ls0],[l1,ls1],[l2,ls2]]}
     (oldest first; FF FF FF shows as 16777215; a byte count 02 reply with status
      FF FF is accepted as "abnormal, no values": kind null, groups null)
  {"event":"diagnostics","index":k,"address":A,"command":14,"status":[14,D],"diag":D,
   "meaning":"healthy"|"element"|"adc"|"power"}
  summary: {"event":"summary","role":"poll-sensor","ok":..,"address":A,"command":C,
            "replies":K,"bad_frames":N[,"error":E,"timeout":true]}

`pull` (request data: the 4-byte ack; first ack --ack, default 0, then the last minute
  of the newest non-empty batch). It stops when a reply has n = 0 (that request
  acknowledged everything before it), or after --stop-after B replies without sending
  the request that would acknowledge the last one. A timed-out request is sent again
  up to --retries (default 3) times. Exit 1 on: response code (status byte 1 != 0),
  byte count != 8 + 22*n, n > 11, more-flag (flags bit 0) != (remaining > 0), n = 0
  with the more-flag set, a record minute not after the ack sent / not increasing,
  a valid bit that disagrees with its counts (FF FF FF iff not valid) or float (NaN
  iff not valid; bit 0 temperature, bit 1 level, bit 2 counts only).
  {"event":"record","minute":M,"valid":V,"t_raw":T,"l_raw":L,"ls_raw":LS,
   "temperature":float|null,"level":float|null}   (floats: the float32 value, exact)
  {"event":"batch","index":i,"ack_sent":A,"status":[S1,S2],"flags":F,"more":bool,
   "remaining":R,"n":n,"first":M|null,"last":M|null}
  {"event":"retry","attempt":k,"address":A,"command":144}
  {"event":"stopped","batches":B,"unacknowledged_last":M}   (--stop-after only)
  summary: {"event":"summary","role":"pull","ok":..,"address":A,"batches":B,
            "records":N,"complete":bool,"last_ack":M,"last_stored":M|null,
            "bad_frames":N}
     last_ack: the ack carried by the last request sent (what the station was told;
     pass it as --ack to resume with the unacknowledged batch sent again);
     last_stored: the newest minute received (pass it to acknowledge everything).

WHAT `concentrator` SERVES: minutes START .. START+COUNT-1, each record
  valid 7, temperature counts 8000000 + minute % 1000, level counts 4000000 +
  minute % 1000, level sensor temperature counts 3000000, temperature float32
  15.0 + (minute % 1000) / 1000, level float32 10.0 + (minute % 1000) / 10000;
  a minute given with --invalid has valid 0, counts FF FF FF and NaN floats.
  Command 144: handed-over mark starts at 0; mark = max(mark, min(ack, newest))
  (with COUNT 0 it never moves); the reply, status 00 00, carries the (at most 11)
  minutes after the mark, flags bit 0 = remaining > 0. Fewer than 4 data bytes:
  response code 5.
  Command 14: status 0E 00, data (big-endian): clock (4) = floor(time/60), stored (4)
  = COUNT, not handed over (4), fill (2) = COUNT*1000 // 20160 (14-day ring), dropped
  (4) = 0, k (1) = 2, then per sensor 7 bytes (address, kind, state, minute (4) -- the
  doc says 6*k but lists 7 bytes): 01 00 00 newest, 02 01 00 newest.
  Command 160: fewer than 35 data bytes: code 5; sensor not 0/1 or segment not 1-10:
  code 2; segment 1 starts a new table for that sensor, segment k > 1 must follow
  segment k-1 of the table being received, else code 9; at segment 10 the table is
  checked (coefficients finite, raw_from <= raw_to, raw_from of k+1 = raw_to of k + 1;
  full 0..FFFFFF coverage is NOT required) and refused with code 10 (reason logged),
  or put in force. Reply status 00 00, data [sensor, segment, 0 taken | 1 in force];
  error replies carry the response code in status byte 1, 00, and no data.
  Any other command: code 64. Other addresses and reply frames: ignored.
  Events: {"event":"ack","ack":A,"mark_before":M,"mark":M,"moved":bool}
          {"event":"batch_sent","n":n,"remaining":R,"first":M|null,"last":M|null}
          {"event":"status_sent","clock":C,"stored":S,"not_handed_over":N,"fill":F}
          {"event":"calibration_segment","sensor":S,"reserved":H,"segment":k,
           "raw_from":F,"raw_to":T,"a0":x,"a1":x,"a2":x}
          {"event":"calibration_in_force","sensor":S,"raw_from":F,"raw_to":T}
          {"event":"calibration_refused","sensor":S,"reason":R}
          {"event":"error_reply","command":C,"code":RC,"reason":R}
  summary (on SIGTERM/SIGINT or after --run-for): {"event":"summary",
    "role":"concentrator","ok":true,"address":A,"requests":N,"acks":[A,...],
    "last_ack":M|null,"mark":M,"bad_frames":N[,"stopped_by_signal":true]}

`raw` events: {"event":"tx_raw","hex":H}, then rx / bad_frame / garbage;
  summary {"event":"summary","role":"raw","ok":true,"frames":N,"bad_frames":N}.
"""

import argparse
import json
import math
import os
import select
import signal
import struct
import sys
import termios
import time

REQUEST = 0x02
REPLY = 0x06
CMD_READ = 1
CMD_DIAG = 14
CMD_HANDOVER = 144
CMD_CALIBRATION = 160
NO_VALUE = 0xFFFFFF
PUBLISHED_REQUEST = bytes.fromhex("FF FF 02 01 01 00 02")
MAX_RECORDS = 11
RECORD_LEN = 22
GAP_S = 0.5  # an incomplete frame older than this is dropped


class ProtocolError(Exception):
    pass


class Timeout(Exception):
    pass


class SetupError(Exception):
    pass


class Stop(Exception):
    pass


# ----------------------------------------------------------------- output


def hexs(b):
    return " ".join("%02X" % x for x in b)


def clean(v):
    """NaN / inf -> None so that stdout stays strict JSON."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [clean(x) for x in v]
    return v


def emit(event, **fields):
    obj = {"event": event, "time": round(time.time(), 3)}
    obj.update(fields)
    sys.stdout.write(json.dumps(clean(obj), allow_nan=False) + "\n")
    sys.stdout.flush()


# ----------------------------------------------------------------- frames


def xor(data):
    x = 0
    for b in data:
        x ^= b
    return x


class Frame:
    def __init__(self, delimiter, address, command, status, data, raw):
        self.delimiter = delimiter
        self.address = address
        self.command = command
        self.status = status  # (s1, s2) for replies, None for requests
        self.data = data  # bytes after the status bytes
        self.raw = raw  # the whole frame as received/sent, preambles included

    @property
    def byte_count(self):
        return len(self.data) + (2 if self.status is not None else 0)

    def describe(self):
        return {
            "hex": hexs(self.raw),
            "delimiter": "request" if self.delimiter == REQUEST else "reply",
            "address": self.address,
            "command": self.command,
            "byte_count": self.byte_count,
            "status": list(self.status) if self.status is not None else None,
            "data": hexs(self.data),
        }


def build_frame(delimiter, address, command, data=b"", status=None):
    payload = (bytes(status) if status is not None else b"") + bytes(data)
    if len(payload) > 255:
        raise ValueError("frame payload too long")
    body = bytes([delimiter, address & 0xFF, command & 0xFF, len(payload)]) + payload
    raw = b"\xff\xff" + body + bytes([xor(body)])
    return Frame(delimiter, address, command,
                 tuple(status) if status is not None else None, bytes(data), raw)


class Deframer:
    """Byte stream -> ('frame', Frame) / ('bad', bytes, reason) / ('garbage', bytes)."""

    def __init__(self):
        self.buf = bytearray()
        self.last_rx = 0.0
        self.quiet = 0  # leading bytes of buf already reported inside a bad frame

    def feed(self, data, now):
        self.buf += data
        self.last_rx = now
        return self._parse(False)

    def pending_partial(self):
        return len(self.buf) > 0

    def expire(self, now):
        if self.buf and now - self.last_rx >= GAP_S:
            return self._parse(True)
        return []

    def _drop(self, n):
        """Remove n leading bytes; returns those not already reported in a bad frame."""
        quiet = min(self.quiet, n)
        out = bytes(self.buf[quiet:n])
        del self.buf[:n]
        self.quiet -= quiet
        return out

    def _bad(self, out, span, keep_from, reason):
        """Report buf[:span] as a bad frame and resume the search at keep_from."""
        out.append(("bad", bytes(self.buf[:span]), reason))
        del self.buf[:keep_from]
        self.quiet = max(0, span - keep_from)

    def _parse(self, final):
        out = []
        buf = self.buf
        while True:
            run = 0
            p = -1
            for i, c in enumerate(buf):
                if c == 0xFF:
                    run += 1
                elif (c == REQUEST or c == REPLY) and run >= 2:
                    p = i
                    break
                else:
                    run = 0
            if p < 0:
                keep = 0 if final else run
                junk = self._drop(len(buf) - keep)
                if any(b != 0xFF for b in junk):
                    out.append(("garbage", junk))
                return out
            start = p - run
            if start > 0:
                junk = self._drop(start)
                if junk:
                    out.append(("garbage", junk))
                p = run
            self.quiet = 0  # a new delimiter: everything from here is reported afresh
            if len(buf) < p + 4:
                if final:
                    self._bad(out, len(buf), p + 1, "incomplete frame")
                    continue
                return out
            delim, bc = buf[p], buf[p + 3]
            if delim == REPLY and bc < 2:
                self._bad(out, p + 4, p + 1, "reply byte count %d < 2" % bc)
                continue
            end = p + 4 + bc + 1
            if len(buf) < end:
                if final:
                    self._bad(out, len(buf), p + 1, "incomplete frame")
                    continue
                return out
            body = bytes(buf[p:end - 1])
            if xor(body) != buf[end - 1]:
                self._bad(out, end, p + 1,
                          "check byte %02X, computed %02X" % (buf[end - 1], xor(body)))
                continue
            payload = body[4:]
            if delim == REPLY:
                status, data = (payload[0], payload[1]), payload[2:]
            else:
                status, data = None, payload
            out.append(("frame", Frame(delim, buf[p + 1], buf[p + 2], status, data,
                                       bytes(buf[:end]))))
            del buf[:end]


# ----------------------------------------------------------------- port


class Port:
    def __init__(self, path):
        self.path = path
        try:
            self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError as e:
            raise SetupError("cannot open %s: %s" % (path, e))
        self.deframer = Deframer()
        self.frames = []
        self.bad_frames = 0
        self._configure()

    def _configure(self):
        baud = None
        parity = "unchanged"
        try:
            attrs = termios.tcgetattr(self.fd)
        except termios.error as e:
            raise SetupError("%s is not a terminal device: %s" % (self.path, e))
        # raw: no input/output processing, no echo, no signals, byte-at-a-time reads
        attrs[0] = termios.IGNBRK | termios.IGNPAR | termios.INPCK  # iflag: drop bad-parity bytes
        attrs[1] = 0  # oflag
        attrs[3] = 0  # lflag
        cc = list(attrs[6])
        cc[termios.VMIN] = 0
        cc[termios.VTIME] = 0
        attrs[6] = cc
        base_cflag = termios.CREAD | termios.CLOCAL
        tries = [
            (base_cflag | termios.CS8 | termios.PARENB | termios.PARODD, termios.B1200),
            (base_cflag | termios.CS8, termios.B1200),
            (base_cflag | termios.CS8, None),
        ]
        for cflag, speed in tries:
            a = list(attrs)
            a[2] = cflag
            if speed is not None:
                a[4] = speed
                a[5] = speed
            try:
                termios.tcsetattr(self.fd, termios.TCSANOW, a)
            except (termios.error, OSError):
                continue
            try:
                got = termios.tcgetattr(self.fd)
                baud = 1200 if got[4] == termios.B1200 else None
                odd = termios.PARENB | termios.PARODD
                parity = "odd" if (got[2] & odd) == odd else "unchanged"
            except termios.error:
                pass
            break
        try:
            termios.tcflush(self.fd, termios.TCIOFLUSH)
        except termios.error:
            pass
        emit("port", path=self.path, raw=True, baud=baud, parity=parity)

    def send(self, frame):
        data = frame.raw
        while data:
            try:
                n = os.write(self.fd, data)
                data = data[n:]
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
            except OSError as e:
                raise ProtocolError("write to %s failed: %s" % (self.path, e))
        try:
            termios.tcdrain(self.fd)
        except (termios.error, OSError):
            pass
        emit("tx", **frame.describe())

    def _handle(self, items):
        for item in items:
            if item[0] == "frame":
                emit("rx", **item[1].describe())
                self.frames.append(item[1])
            elif item[0] == "bad":
                self.bad_frames += 1
                emit("bad_frame", hex=hexs(item[1]), reason=item[2])
            else:
                emit("garbage", hex=hexs(item[1]))

    def recv(self, deadline):
        """Next well-formed frame (check byte right), or None at the deadline
        (deadline None: wait forever)."""
        while True:
            if self.frames:
                return self.frames.pop(0)
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                return None
            wait = 1.0 if deadline is None else deadline - now
            if self.deframer.pending_partial():
                wait = min(wait, max(0.01, self.deframer.last_rx + GAP_S - now))
            r, _, _ = select.select([self.fd], [], [], wait)
            now = time.monotonic()
            if r:
                try:
                    chunk = os.read(self.fd, 4096)
                except BlockingIOError:
                    continue
                except OSError as e:
                    raise ProtocolError("read from %s failed: %s (peer gone?)" % (self.path, e))
                if not chunk:
                    raise ProtocolError("%s closed (peer gone?)" % self.path)
                self._handle(self.deframer.feed(chunk, now))
            else:
                self._handle(self.deframer.expire(now))


def transact(port, request, timeout, retries, accept):
    """Send request, return the first reply frame accepted by accept(frame) (True =
    take it; frames it returns False for are logged as ignored). Retries on timeout."""
    for attempt in range(retries + 1):
        if attempt:
            emit("retry", attempt=attempt, address=request.address, command=request.command)
        port.send(request)
        deadline = time.monotonic() + timeout
        while True:
            f = port.recv(deadline)
            if f is None:
                break
            if accept(f):
                return f
    raise Timeout("no reply from address 0x%02X to command %d within %.3g s (%d attempt%s)"
                  % (request.address, request.command, timeout, retries + 1,
                     "" if retries == 0 else "s"))


def accept_reply(f):
    if f.delimiter != REPLY:
        emit("ignored", reason="request frame heard by a master", address=f.address,
             command=f.command)
        return False
    return True


def u24(b, off):
    return (b[off] << 16) | (b[off + 1] << 8) | b[off + 2]


def p24(v):
    return bytes([(v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF])


def check_reply_header(f, address, command):
    if f.address != address:
        raise ProtocolError("reply address 0x%02X, expected 0x%02X (the address of the "
                            "station that answers)" % (f.address, address))
    if f.command != command:
        raise ProtocolError("reply command %d, expected %d" % (f.command, command))


# ----------------------------------------------------------------- poll-sensor


def role_poll_sensor(args, summary):
    addr = args.address
    if not 1 <= addr <= 15:
        raise SetupError("--address must be 1-15 (a sensor on a well's bus)")
    req = build_frame(REQUEST, addr, args.command)
    if addr == 1 and args.command == 1 and req.raw != PUBLISHED_REQUEST:
        raise ProtocolError("internal: request differs from the published example")
    port = Port(args.path)
    summary["_port"] = port
    summary["address"] = addr
    summary["command"] = args.command
    summary["replies"] = 0
    for k in range(args.count):
        if k:
            time.sleep(0.2)
        f = transact(port, req, args.timeout, args.retries, accept_reply)
        check_reply_header(f, addr, args.command)
        st = f.status
        if args.command == CMD_READ:
            bc = f.byte_count
            if bc == 2 and st[0] != 0 and st != (0xFF, 0xFF):
                raise ProtocolError("sensor answered command 1 with response code %d "
                                    "(status %02X %02X)" % (st[0], st[0], st[1]))
            if st not in ((0, 0), (0xFF, 0xFF)):
                raise ProtocolError("command 1 status %02X %02X is neither 00 00 nor FF FF"
                                    % st)
            abnormal = st == (0xFF, 0xFF)
            d = f.data
            if bc == 0x0B:
                kind = "temperature"
                groups = [u24(d, 3 * i) for i in range(3)]
            elif bc == 0x14:
                kind = "level"
                groups = [[u24(d, 6 * i), u24(d, 6 * i + 3)] for i in range(3)]
            elif bc == 2 and abnormal:
                # docs/wells.md is ambiguous here: "answers command 1 with FF FF and no
                # values" (command 14 section) vs "still carries three groups".
                kind = None
                groups = None
            else:
                raise ProtocolError("command 1 reply byte count %02X, expected 0B "
                                    "(temperature) or 14 (level)" % bc)
            emit("reading", index=k, address=addr, command=1, kind=kind, status=list(st),
                 abnormal=abnormal, groups=groups)
        else:
            if f.byte_count != 2:
                raise ProtocolError("command 14 reply byte count %02X, expected 02"
                                    % f.byte_count)
            if st[0] != 0x0E:
                raise ProtocolError("command 14 status byte 1 is %02X, expected 0E" % st[0])
            if st[1] > 3:
                raise ProtocolError("command 14 diagnosis %02X is not 00-03" % st[1])
            emit("diagnostics", index=k, address=addr, command=14, status=list(st),
                 diag=st[1], meaning=["healthy", "element", "adc", "power"][st[1]])
        summary["replies"] += 1


# ----------------------------------------------------------------- sensors


def sensor_minute(args):
    if args.base_minute is not None:
        return args.base_minute
    return int(time.time() // 60)


def role_sensors(args, summary):
    taddr, laddr = args.temperature_addr, args.level_addr
    for a in (taddr, laddr):
        if not 1 <= a <= 15:
            raise SetupError("sensor addresses must be 1-15")
    if taddr == laddr:
        raise SetupError("--temperature-addr and --level-addr must differ")
    if not 0 <= args.diag <= 3:
        raise SetupError("--diag must be 0-3")
    silent = set(args.silent or [])
    port = Port(args.path)
    summary["answered"] = 0
    summary["ignored"] = 0
    summary["_port"] = port
    stop_at = None if args.run_for is None else time.monotonic() + args.run_for
    while True:
        f = port.recv(stop_at)
        if f is None:
            return
        if f.delimiter != REQUEST:
            emit("ignored", reason="reply frame", address=f.address, command=f.command)
            summary["ignored"] += 1
            continue
        if f.address not in (taddr, laddr):
            emit("ignored", reason="other address", address=f.address, command=f.command)
            summary["ignored"] += 1
            continue
        if f.address in silent:
            emit("ignored", reason="silent", address=f.address, command=f.command)
            summary["ignored"] += 1
            continue
        kind = "temperature" if f.address == taddr else "level"
        minutes = None
        groups = None
        if f.command == CMD_READ:
            t = sensor_minute(args)
            minutes = [t - 3 + i for i in range(3)]
            abnormal = args.status == "abnormal"
            status = (0xFF, 0xFF) if abnormal else (0, 0)
            data = bytearray()
            groups = []
            for m in minutes:
                if kind == "temperature":
                    v = NO_VALUE if abnormal else 8000000 + m % 1000
                    data += p24(v)
                    groups.append(v)
                else:
                    lv = NO_VALUE if abnormal else 4000000 + m % 1000
                    ls = NO_VALUE if abnormal else 3000000
                    data += p24(lv) + p24(ls)
                    groups.append([lv, ls])
        elif f.command == CMD_DIAG:
            status = (0x0E, args.diag)
            data = b""
        else:
            status = (64, 0)
            data = b""
        port.send(build_frame(REPLY, f.address, f.command, data, status))
        emit("answered", address=f.address, command=f.command, kind=kind,
             status=list(status), minutes=minutes, groups=groups)
        summary["answered"] += 1


# ----------------------------------------------------------------- pull


def parse_batch(f, ack_sent):
    st = f.status
    if st[0] != 0:
        raise ProtocolError("command 144 answered with response code %d (status %02X %02X)"
                            % (st[0], st[0], st[1]))
    d = f.data
    if len(d) < 6:
        raise ProtocolError("command 144 reply has %d data bytes, at least 6 expected" % len(d))
    flags = d[0]
    remaining = struct.unpack(">I", d[1:5])[0]
    n = d[5]
    if n > MAX_RECORDS:
        raise ProtocolError("batch of %d records, at most %d allowed" % (n, MAX_RECORDS))
    if len(d) != 6 + RECORD_LEN * n:
        raise ProtocolError("batch of %d records needs byte count %d, got %d"
                            % (n, 2 + 6 + RECORD_LEN * n, f.byte_count))
    more = bool(flags & 1)
    if more != (remaining > 0):
        raise ProtocolError("more-flag %d but %d records remaining" % (int(more), remaining))
    records = []
    prev = ack_sent
    for i in range(n):
        r = d[6 + RECORD_LEN * i: 6 + RECORD_LEN * (i + 1)]
        minute = struct.unpack(">I", r[0:4])[0]
        valid = r[4]
        t_raw, l_raw, ls_raw = u24(r, 5), u24(r, 8), u24(r, 11)
        temperature, level = struct.unpack(">ff", r[14:22])
        if minute <= prev:
            raise ProtocolError("record minute %d not after %d (ack sent %d; records must be "
                                "after the mark, oldest first)" % (minute, prev, ack_sent))
        prev = minute
        for bit, name, raw in ((0, "water temperature", t_raw), (1, "level", l_raw),
                               (2, "level sensor temperature", ls_raw)):
            is_valid = bool(valid & (1 << bit))
            if is_valid and raw == NO_VALUE:
                raise ProtocolError("minute %d: %s valid but counts FF FF FF" % (minute, name))
            if not is_valid and raw != NO_VALUE:
                raise ProtocolError("minute %d: %s not valid but counts %06X"
                                    % (minute, name, raw))
        for bit, name, val in ((0, "temperature", temperature), (1, "level", level)):
            is_valid = bool(valid & (1 << bit))
            if is_valid and not math.isfinite(val):
                raise ProtocolError("minute %d: %s valid but float is %r" % (minute, name, val))
            if not is_valid and not math.isnan(val):
                raise ProtocolError("minute %d: %s not valid but float is %r (NaN expected)"
                                    % (minute, name, val))
        records.append({"minute": minute, "valid": valid, "t_raw": t_raw, "l_raw": l_raw,
                        "ls_raw": ls_raw, "temperature": temperature, "level": level})
    return flags, more, remaining, records


def role_pull(args, summary):
    if args.address is not None:
        addr = args.address
    else:
        if args.well is None or not 1 <= args.well <= 15:
            raise SetupError("--well must be 1-15 (or give --address)")
        addr = 0x80 + args.well
    if not 0 <= addr <= 0xFF:
        raise SetupError("--address must be a byte")
    if not 0 <= args.ack <= 0xFFFFFFFF:
        raise SetupError("--ack must fit 4 bytes")
    port = Port(args.path)
    summary["_port"] = port
    ack = args.ack
    summary.update(address=addr, batches=0, records=0, complete=False, last_ack=ack,
                   last_stored=None)

    while True:
        req = build_frame(REQUEST, addr, CMD_HANDOVER, struct.pack(">I", ack))
        summary["last_ack"] = ack
        f = transact(port, req, args.timeout, args.retries, accept_reply)
        check_reply_header(f, addr, CMD_HANDOVER)
        flags, more, remaining, records = parse_batch(f, ack)
        for r in records:
            emit("record", **r)
        summary["batches"] += 1
        summary["records"] += len(records)
        emit("batch", index=summary["batches"], ack_sent=ack, status=list(f.status),
             flags=flags, more=more, remaining=remaining, n=len(records),
             first=records[0]["minute"] if records else None,
             last=records[-1]["minute"] if records else None)
        if records:
            ack = records[-1]["minute"]
            summary["last_stored"] = ack
        elif more:
            raise ProtocolError("empty batch with the more-flag set (%d remaining)" % remaining)
        else:
            # the request that got this empty reply acknowledged everything before it
            summary["complete"] = True
            return
        if args.stop_after is not None and summary["batches"] >= args.stop_after:
            emit("stopped", batches=summary["batches"], unacknowledged_last=ack)
            return


# ----------------------------------------------------------------- concentrator


CAPACITY_MINUTES = 14 * 24 * 60


class Store:
    def __init__(self, start, count, invalid):
        self.start = start
        self.count = count
        self.end = start + count - 1  # newest minute (count > 0)
        self.invalid = set(invalid)
        self.mark = 0

    def record(self, m):
        if m in self.invalid:
            return (struct.pack(">IB", m, 0) + p24(NO_VALUE) * 3
                    + struct.pack(">ff", float("nan"), float("nan")))
        v = m % 1000
        return (struct.pack(">IB", m, 7) + p24(8000000 + v) + p24(4000000 + v)
                + p24(3000000) + struct.pack(">ff", 15.0 + v / 1000.0, 10.0 + v / 10000.0))

    def not_handed_over(self):
        if self.count == 0:
            return 0
        first = max(self.start, self.mark + 1)
        return max(0, self.end - first + 1)

    def move_mark(self, ack):
        if self.count == 0:
            return self.mark
        self.mark = max(self.mark, min(ack, self.end))
        return self.mark

    def batch(self):
        if self.count == 0:
            return [], 0
        first = max(self.start, self.mark + 1)
        n = max(0, min(MAX_RECORDS, self.end - first + 1))
        minutes = list(range(first, first + n))
        remaining = self.not_handed_over() - n
        return minutes, remaining


def role_concentrator(args, summary):
    if args.address is not None:
        addr = args.address
    else:
        if args.well is None or not 1 <= args.well <= 15:
            raise SetupError("--well must be 1-15 (or give --address)")
        addr = 0x80 + args.well
    start, count = args.minutes
    if start < 0 or count < 0 or start + count - 1 > 0xFFFFFFFF:
        raise SetupError("--minutes START COUNT out of range")
    store = Store(start, count, args.invalid or [])
    pending = {0: None, 1: None}  # sensor -> list of segments being received
    in_force = {0: None, 1: None}
    port = Port(args.path)
    summary["_port"] = port
    summary.update(address=addr, requests=0, acks=[], last_ack=None, mark=store.mark)
    stop_at = None if args.run_for is None else time.monotonic() + args.run_for
    while True:
        f = port.recv(stop_at)
        if f is None:
            return
        if f.delimiter != REQUEST:
            emit("ignored", reason="reply frame", address=f.address, command=f.command)
            continue
        if f.address != addr:
            emit("ignored", reason="other address", address=f.address, command=f.command)
            continue
        summary["requests"] += 1
        status, data = (0, 0), b""
        if f.command == CMD_HANDOVER:
            if len(f.data) < 4:
                status = (5, 0)
                emit("error_reply", command=f.command, code=5, reason="too few data bytes")
            else:
                ack = struct.unpack(">I", f.data[:4])[0]
                before = store.mark
                after = store.move_mark(ack)
                emit("ack", ack=ack, mark_before=before, mark=after, moved=after != before)
                summary["acks"].append(ack)
                summary["last_ack"] = ack
                summary["mark"] = after
                minutes, remaining = store.batch()
                data = (bytes([1 if remaining > 0 else 0]) + struct.pack(">I", remaining)
                        + bytes([len(minutes)]) + b"".join(store.record(m) for m in minutes))
                emit("batch_sent", n=len(minutes), remaining=remaining,
                     first=minutes[0] if minutes else None,
                     last=minutes[-1] if minutes else None)
        elif f.command == CMD_DIAG:
            status = (0x0E, 0)
            newest = store.end if count else 0
            stored = count
            fill = min(1000, stored * 1000 // CAPACITY_MINUTES)
            data = struct.pack(">IIIHIB", int(time.time() // 60), stored,
                               store.not_handed_over(), fill, 0, 2)
            data += struct.pack(">BBBI", 1, 0, 0, newest)
            data += struct.pack(">BBBI", 2, 1, 0, newest)
            emit("status_sent", clock=int(time.time() // 60), stored=stored,
                 not_handed_over=store.not_handed_over(), fill=fill)
        elif f.command == CMD_CALIBRATION:
            status, data = calibration(f.data, pending, in_force)
        else:
            status = (64, 0)
            emit("error_reply", command=f.command, code=64, reason="command not implemented")
        port.send(build_frame(REPLY, addr, f.command, data, status))


def calibration(d, pending, in_force):
    if len(d) < 35:
        emit("error_reply", command=160, code=5, reason="too few data bytes (%d)" % len(d))
        return (5, 0), b""
    sensor, segment = d[0], d[1]
    if sensor not in (0, 1) or not 1 <= segment <= 10:
        emit("error_reply", command=160, code=2,
             reason="invalid selection sensor %d segment %d" % (sensor, segment))
        return (2, 0), b""
    seg = {"segment": segment, "raw_from": u24(d, 2), "raw_to": u24(d, 5),
           "a0": struct.unpack(">d", d[8:16])[0], "a1": struct.unpack(">d", d[16:24])[0],
           "a2": struct.unpack(">d", d[24:32])[0]}
    emit("calibration_segment", sensor=sensor, reserved=hexs(d[32:35]), **seg)
    if segment == 1:
        pending[sensor] = [seg]
    else:
        cur = pending[sensor]
        if cur is None or len(cur) + 1 != segment:
            emit("error_reply", command=160, code=9,
                 reason="segment %d out of order (expected %s)"
                 % (segment, "1" if cur is None else str(len(cur) + 1)))
            return (9, 0), b""
        cur.append(seg)
    result = 0
    if segment == 10:
        table = pending[sensor]
        pending[sensor] = None
        reason = None
        for i, s in enumerate(table):
            if not all(math.isfinite(s[k]) for k in ("a0", "a1", "a2")):
                reason = "segment %d: coefficient not finite" % s["segment"]
            elif s["raw_from"] > s["raw_to"]:
                reason = "segment %d: raw_from > raw_to" % s["segment"]
            elif i and s["raw_from"] != table[i - 1]["raw_to"] + 1:
                reason = "segment %d: not contiguous with segment %d" % (s["segment"], i)
            if reason:
                break
        if reason:
            emit("calibration_refused", sensor=sensor, reason=reason)
            emit("error_reply", command=160, code=10, reason=reason)
            return (10, 0), b""
        in_force[sensor] = table
        result = 1
        emit("calibration_in_force", sensor=sensor, raw_from=table[0]["raw_from"],
             raw_to=table[-1]["raw_to"])
    return (0, 0), bytes([sensor, segment, result])


# ----------------------------------------------------------------- raw


def role_raw(args, summary):
    try:
        data = bytes.fromhex(args.hex)
    except ValueError:
        raise SetupError("HEX is not hex: %r" % args.hex)
    port = Port(args.path)
    summary["_port"] = port
    try:
        os.write(port.fd, data)
    except OSError as e:
        raise ProtocolError("write failed: %s" % e)
    emit("tx_raw", hex=hexs(data))
    deadline = time.monotonic() + args.timeout
    n = 0
    while True:
        f = port.recv(deadline)
        if f is None:
            break
        n += 1
    summary["frames"] = n


# ----------------------------------------------------------------- main


class Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        sys.stderr.write("%s: error: %s\n" % (self.prog, message))
        sys.exit(3)


def int_any(s):
    return int(s, 0)


def main(argv=None):
    p = Parser(description="Independent test peer for the hartkit wells network "
               "(written from docs/wells.md only).")
    sub = p.add_subparsers(dest="role")
    sub.required = True

    a = sub.add_parser("poll-sensor", help="act as a concentrator polling one sensor")
    a.add_argument("path")
    a.add_argument("--address", type=int_any, required=True)
    a.add_argument("--command", type=int, choices=(1, 14), default=1)
    a.add_argument("--count", type=int, default=1)
    a.add_argument("--timeout", type=float, default=2.0, help="seconds per attempt")
    a.add_argument("--retries", type=int, default=0, help="retries on timeout (default 0)")

    a = sub.add_parser("sensors", help="act as the two sensors of a well's bus")
    a.add_argument("path")
    a.add_argument("--temperature-addr", type=int_any, default=1)
    a.add_argument("--level-addr", type=int_any, default=2)
    a.add_argument("--status", choices=("normal", "abnormal"), default="normal")
    a.add_argument("--diag", type=int, default=0)
    a.add_argument("--silent", type=int_any, action="append")
    a.add_argument("--base-minute", type=int, default=None,
                   help="freeze the sensors' clock at this minute (Unix time / 60)")
    a.add_argument("--run-for", type=float, default=None, help="exit 0 after S seconds")

    a = sub.add_parser("pull", help="act as the PC/handheld fetching minutes (command 144)")
    a.add_argument("path")
    a.add_argument("--well", type=int)
    a.add_argument("--address", type=int_any, default=None)
    a.add_argument("--ack", type=int_any, default=0)
    a.add_argument("--stop-after", type=int, default=None)
    a.add_argument("--timeout", type=float, default=4.0, help="seconds per attempt")
    a.add_argument("--retries", type=int, default=3)

    a = sub.add_parser("concentrator", help="act as a concentrator serving stored minutes")
    a.add_argument("path")
    a.add_argument("--well", type=int)
    a.add_argument("--address", type=int_any, default=None)
    a.add_argument("--minutes", type=int, nargs=2, metavar=("START", "COUNT"), required=True)
    a.add_argument("--invalid", type=int, action="append",
                   help="a minute served with valid 0 (repeatable)")
    a.add_argument("--run-for", type=float, default=None, help="exit 0 after S seconds")

    a = sub.add_parser("raw", help="send raw hex bytes, log frames heard")
    a.add_argument("path")
    a.add_argument("hex")
    a.add_argument("--timeout", type=float, default=1.0)

    args = p.parse_args(argv)

    def on_signal(signum, frame):
        raise Stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    roles = {"poll-sensor": role_poll_sensor, "sensors": role_sensors, "pull": role_pull,
             "concentrator": role_concentrator, "raw": role_raw}
    summary = {"role": args.role, "ok": True}
    code = 0
    try:
        roles[args.role](args, summary)
    except Stop:
        summary["stopped_by_signal"] = True
    except ProtocolError as e:
        summary["ok"], summary["error"], code = False, str(e), 1
    except Timeout as e:
        summary["ok"], summary["error"], code = False, str(e), 2
        summary["timeout"] = True
    except SetupError as e:
        summary["ok"], summary["error"], code = False, str(e), 3
    port = summary.pop("_port", None)
    if port is not None:
        summary["bad_frames"] = port.bad_frames
    if code:
        sys.stderr.write("wells_peer %s: %s\n" % (args.role, summary["error"]))
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    emit("summary", **summary)
    return code


if __name__ == "__main__":
    sys.exit(main())
